"""Where the hazard RApp stands to check a door (rapps/hazard_detection/hazard_detection/view.py, issue
42 item 3): a pinhole model of the robot's camera and the original image method's rule for floor lines
predict, before the robot goes anywhere, from where the method decides every opening right."""
import math

import numpy as np
import pytest

from ontology.services.home import DoorShape, DoorwaySpec, RoomSpec
from rapps.hazard_detection.hazard_detection.view import (CameraModel, DoorView, distinct, door_axes, door_views,
                                                          leaf_direction, predicted_readings, view_margin,
                                                          wall_faces)

# the robots' check cameras at 640x480 (robots/nao.py, robots/elektron.py; height and offset as
# get_transform(chain="camera", space="robot") gives them with the head aimed at the floor ~1.5 m away)
NAO = CameraModel(543.6, 543.6, 319.5, 239.5, 640, 480, z=0.48, ahead=0.085)
ELEKTRON = CameraModel(772.5, 772.5, 319.5, 239.5, 640, 480, z=1.035, ahead=-0.076)
# a hall (y < 4) and a bathroom behind a 0.9 m door that opens into it (the robot's side: the hall)
DOOR = DoorShape(hinge=[3.0, 4.0], closed_yaw_deg=0.0, width_m=0.9, opens="left")
ROOMS = [RoomSpec(name="hall", rect=[0.05, 0.05, 7.95, 3.95]), RoomSpec(name="bath", rect=[0.05, 4.05, 7.95, 7.95])]
DOORS = [DoorwaySpec(id="d", door=DOOR, rooms=["hall", "bath"])]
HALL = (3.5, 2.0)
FEW = dict(distances=(0.8, 1.25, 2.1), bearings_deg=(45, 75, 105))  # a few stands: the tests stay cheap


def test_the_door_axes_follow_the_side_the_leaf_opens_to():
    h, c, s, swing = door_axes(DOOR, HALL)
    assert list(h) == [3.0, 4.0] and np.allclose(c, [1, 0]) and np.allclose(s, [0, -1])
    assert swing == -1  # it opens into the bathroom, away from the hall
    assert np.allclose(leaf_direction(c, s, swing, 90.0), [0, 1])
    assert door_axes(DOOR.model_copy(update={"opens": "right"}), HALL)[3] == 1  # towards the hall
    assert door_axes(DOOR.model_copy(update={"opens": None}), HALL)[3] == -1  # unknown: away


def test_the_walls_floor_lines_are_cut_at_the_door():
    faces = wall_faces(ROOMS, DOORS)
    on_door_wall = [(a, b) for a, b in faces if abs(a[1] - 3.95) < 1e-9 and abs(b[1] - 3.95) < 1e-9]
    xs = sorted(round(float(v), 2) for a, b in on_door_wall for v in (a[0], b[0]))
    assert xs == [0.05, 3.0, 3.9, 7.95]


def test_from_straight_in_front_a_wide_open_leaf_leaves_the_naos_image_method_without_its_line():
    """The failure of issue 42 (generated house 5, NAO): from 1 m in front the wide-open leaf's floor line
    is steeper than 30 deg in the image; the half keeps the far wall's line, and the door reads closed."""
    front = (3.2, 3.0)
    readings = predicted_readings(NAO, DOOR, front, HALL, ROOMS, DOORS)
    assert readings[0] < 2.0 and readings[1] > 5.0  # closed and a little open: right
    assert readings[-1] is not None and readings[-1] < 5.0  # 90 deg: the far wall's line, "closed"
    faces = wall_faces(ROOMS, DOORS)
    assert view_margin(NAO, DOOR, front, HALL, faces, faces) < 0


@pytest.mark.parametrize("camera, far_m, far_deg", [(NAO, 1.25, 45), (ELEKTRON, 1.8, 55)], ids=["nao", "elektron"])
def test_the_chosen_view_decides_every_opening_right_even_with_a_cabinet_beside_the_door(camera, far_m, far_deg):
    faces = wall_faces(ROOMS, DOORS)
    views = door_views(DOOR, HALL, camera, ROOMS, DOORS, room_rect=ROOMS[0].rect, **FEW)
    best = views[0]
    assert best.margin > 0 and view_margin(camera, DOOR, (best.x, best.y), HALL, faces, faces) == best.margin
    readings = predicted_readings(camera, DOOR, (best.x, best.y), HALL, ROOMS, DOORS)
    assert readings[0] < 2.0 and all(r is None or r > 8.0 for r in readings[1:])  # closed, then open
    assert math.atan2(4.0 - best.y, 3.0 - best.x) == pytest.approx(best.theta)  # facing the hinge
    # a diagonal view from further off keeps the leaf's line in view at every opening, but it also sees
    # the wall beside the door, where a cabinet's front edge would outscore the wall's floor line
    h, c, s, _ = door_axes(DOOR, HALL)
    far = h + far_m * (math.cos(math.radians(far_deg)) * c + math.sin(math.radians(far_deg)) * s)
    assert view_margin(camera, DOOR, far, HALL, faces, faces, robust=False) > 0
    assert view_margin(camera, DOOR, far, HALL, faces, faces) < 0


def test_a_higher_camera_needs_a_lower_view_of_the_floor():
    """Floor lines turn in the image with the camera's depression: from the same far diagonal stand
    the Elektron's camera (1.03 m) loses the wide-open leaf's line that the NAO's (0.48 m) keeps."""
    h, c, s, _ = door_axes(DOOR, HALL)
    stand = h + 1.25 * (math.cos(math.radians(45)) * c + math.sin(math.radians(45)) * s)
    nao = predicted_readings(NAO, DOOR, stand, HALL, ROOMS, DOORS)
    elektron = predicted_readings(ELEKTRON, DOOR, stand, HALL, ROOMS, DOORS)
    assert all(r is not None for r in nao) and nao[-1] > 30
    assert elektron[0] is None  # even the closed door's lines are steeper than 30 deg: "open"


def test_views_stay_in_the_room_and_out_of_a_leaf_opening_towards_them():
    towards = DOOR.model_copy(update={"opens": "right"})  # swings into the hall, where the robot is
    for v in door_views(towards, HALL, NAO, ROOMS, [DoorwaySpec(id="d", door=towards)], room_rect=ROOMS[0].rect,
                        distances=(0.8, 1.4, 2.5), bearings_deg=(15, 45, 75, 135, 165)):
        assert 0.05 + 0.40 <= v.x <= 7.95 - 0.40 and 0.05 + 0.40 <= v.y <= 3.95 - 0.40
        p = np.array([v.x, v.y]) - [3.0, 4.0]
        inside_sweep = p[0] >= 0 and p[1] <= 0
        assert not inside_sweep or np.hypot(*p) >= 0.9 + 0.35 + 0.10


def test_a_second_look_is_from_elsewhere():
    views = [DoorView(x, 0.0, 0.0, (0, 0, 0), 3.0, 1.0, 45) for x in (0.0, 0.1, 0.5, 0.55, 1.2)]
    assert [v.x for v in distinct(views, 0.4)] == [0.0, 0.5, 1.2]
