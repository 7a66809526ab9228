"""A frame that held none of the codes it was aimed at, when the pose's heading was too uncertain to aim
well (after big turns): the localizer looks to either side before it calls the codes hidden
(rapps/sdk/localize.py looks_beside). Full house, NAO house seed 9723: after two 180-degree turns the
robot's heading was 0.22 rad off; four relocalizations each aimed one frame at QR-LIVING-E5, found it
empty, gave up, and the NAO walked 1.2 m off its path (30.5 cm)."""
import logging
from types import SimpleNamespace

import numpy as np
import pytest

from ontology.services.common import Pose2D
from ontology.services.home import HomeInfo
from rapps.sdk.ekf import PoseEKF
from rapps.sdk.localize import HEADS, Localizer, LocalizeSettings, Look, in_frame, looks_beside, plan_looks

from .test_localize_plan import CAMERAS, LANDMARKS, ROOMS, SETTINGS

CAM = CAMERAS["nao"]
# (where the NAO stood, the head yaw the localizer aimed at E5 from where it believed it stood)
AIMS = [((7.279, 3.773, 1.765), -1.25), ((7.234, 4.049, 1.741), -1.45)]
BELIEVED = (7.26, 3.78, 1.99)  # where it believed it stood first
E5 = "QR-LIVING-E5"


def shows(pose, yaw: float, code: str = E5) -> bool:
    inside, _ = in_frame(pose, np.array([yaw]), [LANDMARKS[code]], CAM, 0.0)
    return bool(inside[0, 0])


@pytest.mark.parametrize("true, aim", AIMS)
def test_an_uncertain_aim_looks_beside_and_finds_the_code_a_certain_one_does_not(true, aim):
    assert any(E5 in lk.codes for lk in plan_looks(BELIEVED, 0.05, 0.3, LANDMARKS, ROOMS, CAM, SETTINGS))
    first = Look(aim, [E5], 0.01, 0.005)
    assert not shows(true, first.yaw)  # the aim from the believed heading misses the code
    beside = looks_beside(first, 0.3 + 0.05, 0.15, CAM, frames_left=5)
    assert beside and all(lk.beside and lk.codes == first.codes and abs(lk.yaw) <= CAM.limit for lk in beside)
    assert any(shows(true, lk.yaw) for lk in beside[:2])  # the first to either side
    assert looks_beside(first, 0.02, 0.15, CAM, frames_left=5) == []  # a certain aim: the code is hidden
    assert looks_beside(beside[0], 0.35, 0.15, CAM, frames_left=5) == []  # no looks beside a look beside
    assert len(looks_beside(first, 2.0, 0.15, CAM, frames_left=2)) == 2  # the frame budget holds


class Task:
    """What the localizer uses of a task here: a Cloud Agent that finds nothing in any frame."""

    def __init__(self):
        self.params: dict = {}
        self.robot_info = SimpleNamespace(robot_type="nao")
        self.log = logging.getLogger("test")
        self.robot = SimpleNamespace(get_global_pose=self._pose)

        class Cloud:
            async def call(self, action, _timeout=60.0, _ontology=None, **fields):
                assert action == "observe"
                return SimpleNamespace(items=[])  # every frame empty: the codes are hidden after all

        self.cloud = Cloud()

    async def _pose(self):
        return Pose2D(x=BELIEVED[0], y=BELIEVED[1], theta=BELIEVED[2])


async def test_empty_frames_beside_then_the_code_is_missed():
    task = Task()
    loc = Localizer(task, LocalizeSettings(), home=HomeInfo(home_id="h", map_id="m", landmarks=LANDMARKS))  # type: ignore[arg-type]
    loc.head, loc.camera, loc.intrinsics = HEADS["HeadYaw"], CAM, {}
    loc.ekf, loc.odom_ref = PoseEKF(BELIEVED, 0.05, 0.3), BELIEVED
    first = Look(-1.25, [E5], 0.01, 0.005)
    loc.state = dict(observations=[], localization=None, prior=None, frames=1, empty=0, turned=0.0, yaw=first.yaw,
                     turn=None, turn_done=True, missed=set(), look=first, looks=[], frame=SimpleNamespace(data_b64=""),
                     camera_to_robot=np.eye(4).tolist())
    assert await loc.detect({}) is False
    beside = list(loc.state["looks"])
    assert beside and all(lk.beside for lk in beside) and E5 not in loc.state["missed"]
    while loc.state["looks"] and loc.state["looks"][0].beside:  # each looked at, each empty
        loc.state.update(look=loc.state["looks"].pop(0), frame=SimpleNamespace(data_b64=""))
        loc.state["frames"] += 1
        assert await loc.detect({}) is False
    assert E5 in loc.state["missed"]  # hidden after all: not sought again in this localization
    assert loc.state["empty"] == 1 + len(beside)
