"""Where the SDK's localization looks (rapps/sdk/localize.py plan_looks): only at head angles where the
landmark map and the pose estimate put a decodable code of the robot's room inside the real camera's
frame, the most informative first, until the predicted fix is certain enough."""
import math

import numpy as np
import pytest

from ontology.services.home import RoomSpec
from rapps.sdk.landmarks import corners_world, project
from ontology.services.home import DoorShape, DoorwaySpec
from rapps.sdk.localize import HeadCamera, LocalizeSettings, candidates, in_sight, plan_looks, views_at
from robots.floorplan import load_plan
from robots.nao import SPEC as NAO
from robots.elektron import SPEC as ELEKTRON
from scenarios.home_setup import landmark_specs

PLAN = load_plan("robots/houses/house.yaml", 1)
LANDMARKS = landmark_specs(PLAN)
ROOMS = [RoomSpec(name=r.name, rect=list(r.rect)) for r in PLAN.rooms]
SETTINGS = LocalizeSettings()


def head_camera(spec, z: float, tilt: float, limit: float) -> HeadCamera:
    """The robot's localization camera at 1280x960 with its real horizontal field of view."""
    w, h = 1280, 960
    f = (w / 2) / math.tan(math.radians(spec.cameras[0].hfov_deg) / 2)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    optical = np.column_stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]])  # x right, y down, z forward
    c, s = math.cos(tilt), math.sin(tilt)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ optical
    T[:3, 3] = [0.05, 0.0, z]
    return HeadCamera(K, w, h, T, (0.0, 0.0), limit)


CAMERAS = {"nao": head_camera(NAO, 0.48, -0.12, 2.0), "elektron": head_camera(ELEKTRON, 1.0, 0.12, 2.7)}


@pytest.mark.parametrize("robot", ["nao", "elektron"])
@pytest.mark.parametrize("pose", [(3.0, 12.5, 0.0), (6.0, 12.0, 1.57), (4.0, 5.0, 0.0), (9.0, 17.5, -2.0)])
def test_every_planned_frame_shows_codes_of_the_room_inside_the_real_field_of_view(robot, pose):
    camera = CAMERAS[robot]
    looks = plan_looks(pose, 0.02, 0.01, LANDMARKS, ROOMS, camera, SETTINGS)
    assert looks, "a room with codes on its walls: something to look at"
    room = PLAN.room_at(pose[0], pose[1])
    for look in looks:
        assert abs(look.yaw) <= camera.limit and look.codes
        for text in look.codes:
            lm = LANDMARKS[text]
            assert lm.room == room  # walls hide the other rooms' codes
            uv, depth = project(pose, views_at(pose, look.yaw, {text: lm}, camera, 0.0)[0][1])
            assert np.all(depth > 0) and np.all((uv >= 0) & (uv <= [camera.width, camera.height]))
    assert looks[-1].predicted_std_m <= SETTINGS.max_std_m and looks[-1].predicted_std_rad <= SETTINGS.max_std_rad
    assert len(looks) <= 3  # not a sweep: a few frames, each with a code not seen before
    assert len({c for look in looks for c in look.codes}) >= 2


def test_walls_hide_codes_but_through_a_doorway():
    d_living = next(d for d in PLAN.doors if d.id == "d_living")  # hinge (4, 10), 1 m along x
    doors = [DoorwaySpec(id="d_living", door=DoorShape(hinge=list(d_living.hinge), width_m=d_living.width,
                                                       closed_yaw_deg=math.degrees(d_living.closed_yaw)))]
    assert in_sight((4.5, 12.0), (4.5, 2.0), ROOMS, doors)  # hall -> living through the door's gap
    assert not in_sight((4.5, 12.0), (4.5, 2.0), ROOMS, [])  # the same line, no door there: a wall
    assert not in_sight((7.0, 12.0), (7.0, 2.0), ROOMS, doors)  # beside the door: the wall
    assert in_sight((7.0, 12.0), (2.0, 11.0), ROOMS, doors) and in_sight((1, 1), (2, 2), [], [])


def test_each_code_is_judged_at_its_own_printed_size():
    """The kitchen's 0.25 m codes decode from nearer than the living room's 0.35 m ones."""
    camera = CAMERAS["nao"]
    kitchen, living = LANDMARKS["QR-KITCHEN-E"], LANDMARKS["QR-LIVING-W3"]
    assert (kitchen.size_m, living.size_m) == (0.25, 0.35)
    for lm, room_x in ((kitchen, -1), (living, 1)):
        for d, seen in ((3.0, True), (4.5, lm.size_m == 0.35)):
            pose = (lm.x + room_x * d, lm.y, 0.0)
            near = candidates(pose, {"c": lm}, ROOMS, camera, SETTINGS)
            assert bool(near) == seen, (lm.size_m, d)


def test_no_frame_where_no_code_is_expected():
    camera = CAMERAS["nao"]
    # the bedroom's two small codes are beyond decoding range from its far corner: nothing to capture
    assert plan_looks((13.0, 19.0, 0.0), 0.02, 0.01, LANDMARKS, ROOMS, camera, SETTINGS) == []
    # along the hall's south wall: its codes are seen too obliquely, the north wall's face the robot
    near = candidates((3.0, 10.3, 0.0), LANDMARKS, ROOMS, camera, SETTINGS)
    assert "QR-HALL-S1" not in near and "QR-HALL-N5" in near


def test_an_uncertain_pose_keeps_the_codes_away_from_the_frame_edges():
    camera, pose = CAMERAS["nao"], (6.0, 12.0, 1.57)
    sure = plan_looks(pose, 0.01, 0.005, LANDMARKS, ROOMS, camera, SETTINGS)
    unsure = plan_looks(pose, 0.3, 0.15, LANDMARKS, ROOMS, camera, SETTINGS)

    def worst_edge(looks):
        out = []
        for look in looks:
            for text in look.codes:
                uv, _ = project(pose, views_at(pose, look.yaw, {text: LANDMARKS[text]}, camera, 0.0)[0][1])
                out.append(min(uv[:, 0].min(), camera.width - uv[:, 0].max()))
        return min(out)

    assert worst_edge(unsure) > worst_edge(sure) and worst_edge(unsure) >= camera.width / 4 - 1
    assert corners_world(LANDMARKS["QR-HALL-N1"]).shape == (4, 3)
