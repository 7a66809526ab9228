"""Face recognition of registered people (agents/services/faces.py) on real photographs (tests/data/faces,
from registry packages) and on a robot's camera images of simulated people wearing such faces."""
from __future__ import annotations

import base64
import random
from pathlib import Path

import cv2
import numpy as np
import pytest

from agents.services import faces
from agents.services.context import ServiceContext
from agents.services.errors import ServiceError
from agents.services.images import encode_image
from ontology.services.vision import ForgetFace, LearnFace, ListFaces, RecognizeFaces

FACES = Path(__file__).resolve().parent.parent / "data" / "faces"
STRANGERS = sorted(p.stem for p in FACES.glob("stranger-*.jpg"))


def photo(name: str) -> str:
    return base64.b64encode((FACES / f"{name}.jpg").read_bytes()).decode("ascii")


def names_in(ctx, b64: str) -> list[str]:
    return [f.name for f in faces.recognize_faces(RecognizeFaces(image_b64=b64), ctx).faces]


@pytest.fixture(scope="module")
def described() -> dict[str, np.ndarray]:
    """Each photograph's largest face, described as the service describes it (computed once)."""
    out = {}
    for path in sorted(FACES.glob("*.jpg")):
        img = cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_COLOR)
        out[path.stem] = faces.describe(img, faces.find_faces(img)[0])
    return out


def test_registered_people_are_named_and_strangers_are_unknown(ctx, described):
    learned = faces.learn_face(LearnFace(name="Barack", images_b64=[photo("obama-1"), photo("obama-2")]), ctx)
    assert (learned.used, learned.samples, learned.skipped) == (2, 2, [])
    faces.learn_face(LearnFace(name="Joe", images_b64=[photo("biden-1")]), ctx)
    reply = faces.recognize_faces(RecognizeFaces(image_b64=photo("obama-3")), ctx)
    assert [f.name for f in reply.faces] == ["Barack"] and reply.faces[0].distance < 0.5
    two = faces.recognize_faces(RecognizeFaces(image_b64=photo("stranger-12")), ctx).faces  # a neighbour in the frame
    assert [f.name for f in two] == ["", ""] and two[0].nearest in ("Barack", "Joe") and two[0].distance >= 0.6
    # fifteen people nobody registered: none of them is taken for Barack or Joe (the service's rule)
    known = faces.gallery(ctx).of("alice")
    assert {s: faces.nearest(known, described[s])[1] >= 0.6 for s in STRANGERS} == {s: True for s in STRANGERS}


def test_verification_accuracy_on_the_photographs(described):
    """Every pair of photographs, one registered and the other asked at dlib's 0.6: the three pairs of
    one person (Obama) must be accepted; of the 168 pairs of different people at most 10 % may be
    (docs/face-recognition.md has the figures)."""
    names = sorted(described)
    pairs = [(a, b, float(np.linalg.norm(described[a] - described[b]))) for a in names for b in names if a < b]
    same = [d for a, b, d in pairs if a[:5] == b[:5] == "obama"]
    other = [d for a, b, d in pairs if not a[:5] == b[:5] == "obama"]
    assert len(same) == 3 and len(other) == 168
    assert max(same) < 0.6
    assert sum(d < 0.6 for d in other) <= 0.1 * len(other)


def test_bad_input_is_refused_with_a_reason(ctx):
    with pytest.raises(ServiceError, match="no faces registered") as e:
        faces.recognize_faces(RecognizeFaces(image_b64=photo("obama-1")), ctx)
    assert e.value.code == "no_models"
    blank = encode_image(np.full((120, 160, 3), 200, np.uint8))
    with pytest.raises(ServiceError, match="no frontal face found in any of the 1 images") as e:
        faces.learn_face(LearnFace(name="wall", images_b64=[blank]), ctx)
    assert e.value.code == "no_features"
    with pytest.raises(ServiceError, match="could not be decoded"):
        faces.learn_face(LearnFace(name="x", images_b64=[base64.b64encode(b"not an image").decode()]), ctx)
    learned = faces.learn_face(LearnFace(name="Barack", images_b64=[blank, photo("obama-1")]), ctx)
    assert learned.used == 1 and learned.skipped == ["image 1: no frontal face found"]
    assert names_in(ctx, blank) == []  # nobody in the picture


def test_people_are_listed_added_to_and_forgotten_per_user(ctx):
    faces.learn_face(LearnFace(name="Barack", images_b64=[photo("obama-1")]), ctx)
    faces.learn_face(LearnFace(name="Barack", images_b64=[photo("obama-2")]), ctx)  # adds a sample
    faces.learn_face(LearnFace(name="Joe", images_b64=[photo("biden-1")]), ctx)
    assert [(p.name, p.samples) for p in faces.list_faces(ListFaces(), ctx).people] == [("Barack", 2), ("Joe", 1)]
    bob = ServiceContext(user="bob", state=ctx.state)
    assert faces.list_faces(ListFaces(), bob).people == []  # another user's gallery is their own
    with pytest.raises(ServiceError, match="no faces registered"):
        faces.recognize_faces(RecognizeFaces(image_b64=photo("obama-3")), bob)
    assert [p.name for p in faces.forget_face(ForgetFace(name="Joe"), ctx).people] == ["Barack"]
    with pytest.raises(ServiceError, match="no person 'Joe'"):
        faces.forget_face(ForgetFace(name="Joe"), ctx)
    assert faces.forget_face(ForgetFace(), ctx).people == []


async def test_a_simulated_person_wearing_a_registered_face_is_named_from_a_robots_camera(ctx, tmp_path):
    """The NAO looks at two people standing in the small house's living room, 1.5-2.2 m ahead of it
    (drawn at run time): one
    wears Obama's face (a photograph other than the two he was registered from), one a stranger's."""
    from ontology.robot import CaptureImage, LookAtPoint
    from robots import RobotAPI, World

    seed = random.randrange(10_000)
    rng = random.Random(seed)
    textures = {}
    for name in ("obama-3", "stranger-03"):  # the face as a person would wear it: the face, a little margin
        img = cv2.imread(str(FACES / f"{name}.jpg"))
        x, y, w, h = faces.find_faces(img)[0]
        m = int(0.15 * w)
        textures[name] = tmp_path / f"{name}.png"
        cv2.imwrite(str(textures[name]), img[y - m:y + h + m, x - m:x + w + m])
    faces.learn_face(LearnFace(name="Barack", images_b64=[photo("obama-1"), photo("obama-2")]), ctx)
    spots = {"obama-3": (2.7, 2.4), "stranger-03": (2.7, 1.2)}  # in the living room, facing west
    people = [{"kind": "person", "id": n, "route": [[x + 0.4, y], [x, y]], "speed": 1.0, "face": str(textures[n])}
              for n, (x, y) in spots.items()]
    world = World.from_file("small", seed=seed % 100, overrides={"doors": {"d1": 0}}, disturbances=people)
    try:
        distance, side = rng.uniform(1.5, 2.2), rng.uniform(-0.2, 0.2)
        api = RobotAPI(world.add_robot("nao", pose=(2.7 - distance, 1.8 + side, 0.0)))
        await world.sleep(1.0)  # both have walked to their spot and turned to the robot
        seen = {}
        for name, (x, y) in spots.items():
            await api.look_at_point(LookAtPoint(x=x, y=y, z=1.58))
            shot = await api.capture_image(CaptureImage(resolution="VGA"))
            found = faces.recognize_faces(RecognizeFaces(image_b64=shot.data_b64), ctx).faces
            # the face looked at first; from beyond ~2 m the other person is in the frame too
            seen[name] = [f.name for f in sorted(found, key=lambda f: abs(f.box.x + f.box.width / 2 - 320))]
            (tmp_path / f"{name}-seen.jpg").write_bytes(base64.b64decode(shot.data_b64))
        assert seen["obama-3"][:1] == ["Barack"] and seen["stranger-03"][:1] == [""], (seed, round(distance, 2), seen)
        assert sorted(seen["obama-3"]) in (["Barack"], ["", "Barack"]), seen  # the other one, if seen, named right
        assert sorted(seen["stranger-03"]) in ([""], ["", "Barack"]), seen
    finally:
        world.close()
