"""The Platform's service table (agents/services/registry.py): one row per service, named as its
action in ontology/services/; the pooled column and the state a pooled call reads and writes give the
answers pool.py's name-keyed chains gave before the table (POOLED, _taken, _GIVEN_BACK, _merge); and
the state travels as the pool carries it (in one process here; tests/test_platform_pool.py and
tests/test_platform_restart.py go through real worker processes)."""
from __future__ import annotations

import numpy as np
import pytest

import ontology.services  # noqa: F401 - registers every service action
from agents.platform_directory import REPLICATED
from agents.services import SERVICES
from agents.services.context import ServiceContext, ServiceState
from agents.services.faces import gallery
from agents.services.home import homes
from agents.services.pool import _merge, _taken
from agents.services.state_parts import STORES, travel
from agents.services.vision import models
from ontology.registry import actions
from ontology.services.common import Pose2D
from ontology.services.home import HazardSpec, HomeInfo, RoomSpec
from ontology.services.speech import SpeechNoiseProfile, SpeechRecognition
from ontology.services.vision import FindObjects, LearnFace, RecognizeFaces

from .test_saved import _wav_noise

# ---------------------------------------------------------------- the answers before the table
OLD_POOLED = {
    "qr_detection", "face_detection", "human_detection", "object_detection_find_objects",
    "hazard_detection_door_check", "hazard_detection_light_check",
    "speech_recognition", "speech_noise_profile", "text_to_speech",
    "path_planning_plan_path_2d", "face_recognition_learn", "face_recognition_recognize",
}
OLD_GIVEN_BACK = {"speech_noise_profile": ("speech_noise_profiles",), "face_recognition_learn": ("faces",)}
OLD_TAKEN = {"object_detection_find_objects": {"objects"}, "speech_recognition": {"speech_noise_profiles", "homes"},
             "speech_noise_profile": {"speech_noise_profiles"},
             "face_recognition_learn": {"faces"}, "face_recognition_recognize": {"faces"}}


def test_one_row_per_service_action_of_the_ontology():
    registered = {n for n, c in actions("platform").items() if c.__module__.startswith("ontology.services.")}
    assert set(SERVICES) == registered
    for name, spec in SERVICES.items():
        assert spec.request.action_name == name and spec.reply is spec.request.reply_model


def test_the_table_gives_the_pools_answers_from_before_it():
    assert {n for n, s in SERVICES.items() if s.pooled} == OLD_POOLED
    assert {n: s.writes for n, s in SERVICES.items() if s.writes} == OLD_GIVEN_BACK
    assert {n: set(s.reads) for n, s in SERVICES.items() if s.reads} == OLD_TAKEN
    assert [n for n, s in SERVICES.items() if s.on_map] == ["path_planning_plan_path_2d"]


def test_only_pooled_rows_carry_state_and_every_store_named_travels():
    for name, spec in SERVICES.items():
        if not spec.pooled:  # a threaded call works on the Platform's whole state
            assert not (spec.reads or spec.writes or spec.on_map), name
        assert set(spec.reads) | set(spec.writes) <= set(STORES), name
    for name in REPLICATED:  # a replica has no one's state: what it serves reads and writes none
        assert name in SERVICES and not (SERVICES[name].reads or SERVICES[name].writes), name


def _ctx(user: str = "ann") -> ServiceContext:
    return ServiceContext(user=user, state=ServiceState())


def test_a_pooled_call_takes_only_the_callers_own_entries():
    ctx = _ctx()
    models(ctx).models = {"ann": {"mug": "ann's"}, "bob": {"cup": "bob's"}}
    g = gallery(ctx)
    g.people = {"ann": {"Carol": np.ones((1, 128)), "Dan": np.zeros((1, 128))}, "bob": {"Eve": np.ones((1, 128))}}
    assert _taken(SERVICES["object_detection_find_objects"], FindObjects(image_b64="x"), ctx) == \
        {"objects": {"ann": {"mug": "ann's"}}}
    learn = _taken(SERVICES["face_recognition_learn"], LearnFace(name="Carol", images_b64=["x"]), ctx)
    assert list(learn["faces"]) == ["ann"] and list(learn["faces"]["ann"]) == ["Carol"]
    assert _taken(SERVICES["face_recognition_learn"], LearnFace(name="Zoe", images_b64=["x"]), ctx) == \
        {"faces": {"ann": {}}}
    assert list(_taken(SERVICES["face_recognition_recognize"], RecognizeFaces(image_b64="x"), ctx)["faces"]["ann"]) \
        == ["Carol", "Dan"]


def test_speech_takes_a_named_profile_and_rooms_only_when_asked():
    ctx = _ctx()
    profile = np.arange(4.0)
    ctx.state.store("speech_noise_profiles", dict)[("ann", "kitchen")] = profile
    stand = Pose2D(x=1.0, y=1.0)
    homes(ctx.state).put("ann", HomeInfo(home_id="home", map_id="m", rooms=[RoomSpec(name="hall", rect=[0, 0, 2, 2])],
                                         hazards=[HazardSpec(id="l1", type="lamp", stand=stand, look_at=[1, 2, 1])]))
    spec = SERVICES["speech_recognition"]
    assert _taken(spec, SpeechRecognition(audio_b64="x", sentences=["go"]), ctx) == {}
    taken = _taken(spec, SpeechRecognition(audio_b64="x", sentences=["go to the {room}"], noise_profile="kitchen"), ctx)
    assert taken["speech_noise_profiles"][("ann", "kitchen")] is profile
    [(key, info)] = taken["homes"].items()
    assert key == ("ann", "home") and [r.name for r in info.rooms] == ["hall"] and info.hazards == []
    assert _taken(spec, SpeechRecognition(audio_b64="x", noise_profile="garage"), ctx) == {"speech_noise_profiles": {}}


def test_what_a_pooled_call_stores_comes_back_into_the_platforms_state():
    """The pool's round trip in one process: take, run on a worker's own state, give back, merge."""
    platform = _ctx()
    spec, req = SERVICES["speech_noise_profile"], SpeechNoiseProfile(audio_b64=_wav_noise(), name="kitchen")
    worker = ServiceState()
    worker._stores = {name: travel(name).unpack(part) for name, part in _taken(spec, req, platform).items()}
    spec.run(req, ServiceContext(user="ann", state=worker))
    given = {name: travel(name).pack(worker._stores[name]) for name in spec.writes}
    assert ("ann", "kitchen") not in platform.state.store("speech_noise_profiles", dict)
    _merge(platform, given)
    assert ("ann", "kitchen") in platform.state.store("speech_noise_profiles", dict)

    _merge(platform, {"faces": {"ann": {"Carol": np.ones((2, 128))}, "bob": {"Eve": np.ones((1, 128))}}})
    assert list(gallery(platform).of("ann")) == ["Carol"] and gallery(platform).of("bob") == {}  # the caller's only


WRITTEN = sorted({name for spec in SERVICES.values() for name in spec.writes})


@pytest.mark.parametrize("name", WRITTEN)
def test_every_store_a_call_writes_packs_back_to_plain_data(name):
    part = {("ann", "x"): np.arange(3.0)} if name == "speech_noise_profiles" else {"ann": {"Carol": np.ones((1, 128))}}
    how = travel(name)
    back = how.pack(how.unpack(part))
    assert type(back) is dict and back.keys() == part.keys()
