"""Localization by the home's QR landmarks, for any RApp (paper 001: QR-code global localization with
EKF relative localization; paper 000 fig. 16 s2, the self-localization sub-FSM).

    estimate = await self.localize()      # in a Task: PoseEstimate(x, y, theta, std_m, std_rad, ...)

`self.robot.get_global_pose()` is the robot's odometry: it drifts as the robot walks (docs/sdk.md,
"Where the robot is"). `localize()` looks at the landmarks the home description lists (each with its
own printed size), has the RApp's Cloud Agent find them in the frames and solve the pose
(rapps/sdk/landmark_cloud.py), fuses that fix into a pose EKF (rapps/sdk/ekf.py) that has followed the
odometry since the last fix, sets the fused pose on the robot and returns it with its uncertainty.

Where to look: from the landmark map and the pose estimate, the head angles at which codes should be
in view, decodable (near enough for their size, seen not too obliquely) and in the robot's room; the
next frame is the one predicted to fix the pose best (the corners' information, rapps/sdk/landmarks.py),
and no frame is captured where no code is expected. When no code is in reach of the head the body turns
toward them, once. Looking stops once the fix is certain enough (`LocalizeSettings.std_m`)."""
from __future__ import annotations

import asyncio
import functools
import math
from collections.abc import Awaitable, Callable, Collection, Coroutine, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Protocol, TypedDict, TypeVar, cast

import numpy as np

from agents.errors import RequestError, RequestFailed
from behaviours import FSM
from behaviours.behaviour import Context
from ontology.landmarks import ONTOLOGY as LANDMARKS
from ontology.landmarks import Localization, Observations
from ontology.registry import Content
from ontology.services.common import Pose2D
from ontology.services.home import DoorwaySpec, HomeInfo, LandmarkSpec, RoomSpec

from .ekf import CHI2_3DOF_99, ODOMETRY, OdometryModel, PoseEKF
from .landmarks import PIXEL_NOISE, View, corners_world, information, observed_views, std_from_information
from .calls import PlatformCalls, RobotCalls
from .step import Step


class _Cloud(Protocol):
    async def call(self, action: str, _timeout: float = 60.0, _ontology: str | None = None,
                   **fields: Any) -> Content: ...


class LocalizingTask(Protocol):
    """What the localization uses of a Task (rapps.sdk.Task, which imports this module)."""

    @property
    def runtime(self) -> Any: ...  # the DynamicAgent

    @property
    def params(self) -> Mapping[str, Any]: ...

    @property
    def robot_info(self) -> Any: ...  # ontology.spawn.RobotInfo

    @property
    def robot(self) -> RobotCalls: ...

    @property
    def platform(self) -> PlatformCalls: ...

    @property
    def log(self) -> Any: ...  # rapps.sdk.TaskLog

    @property
    def cloud(self) -> _Cloud: ...


class Head(TypedDict):
    yaw: str  # the head's joints
    pitch: str
    limit: float
    tilt: float


# head joints, reach (rad) and the pitch to look at landmarks at 0.7 m (positive = down), per robot model
HEADS: dict[str, Head] = {
    "HeadYaw": {"yaw": "HeadYaw", "pitch": "HeadPitch", "limit": 2.0, "tilt": -0.12},  # camera ~0.5 m: look up
    "HeadPan": {"yaw": "HeadPan", "pitch": "HeadTilt", "limit": 2.7, "tilt": 0.12},
}

START_STD_M, START_STD_RAD = 0.5, 0.3  # the start pose the robot was given is hardly trusted
# a fix's standard deviations come from the corners' pixel noise only; the camera's pose on the robot,
# the printed codes and the map add their own: never trust a fix more than this
FIX_FLOOR_M, FIX_FLOOR_RAD = 0.004, 0.002
FUSE_MAX_STD_M, FUSE_MAX_STD_RAD = 0.10, 0.05  # a fix less certain than this is no fix at all
# one code too far for a fix of its own (landmark_cloud.SINGLE_MAX_M) is weighed in all the same when the
# filter's position is this many times less certain than it, and its heading less certain at all (a start
# pose hardly trusted, a robot lost)
LOST_FACTOR = 3.0
# a filter less certain than this cannot tell a label moved since the map was made (0.1-0.3 m along its wall)
# from a right one by its gate: a fix it is to take must rest on two codes that agree, or be looked for further
CHECKABLE_STD_M = 0.1
YAW_STEP = 0.05  # rad between the head angles considered
TURNS_DEG = (45, -45, 90, -90, 135, -135, 180)  # body turns tried when the head cannot reach a code


@dataclass
class LocalizeSettings:
    """How a RApp localizes; `from_params` reads them from its manifest's params (names in brackets)."""

    resolution: str = "1280x960"  # [localize_resolution] 0.35 m codes decode up to ~5 m on a NAO
    std_m: float = 0.008  # [localize_std_m] stop looking once the fix is this certain (1 sigma)
    std_rad: float = 0.003  # [localize_std_rad]
    max_std_m: float = 0.02  # [localize_max_std_m] a less certain fix is fused only if it agrees with the EKF
    max_std_rad: float = 0.008  # [localize_max_std_rad]
    max_distance_m: float = 6.0  # [max_marker_distance_m] farther codes are ignored (too inaccurate)
    turn_body: bool = True  # [look_behind] no certain fix within the head's reach: turn the body, once
    max_frames: int = 6  # [localize_max_frames] frames per localization at most
    min_code_px: float = 75.0  # a code smaller than this in the image (its side, px) may not decode
    max_view_deg: float = 60.0  # ... nor one seen further than this off its normal

    PARAMS = {"resolution": "localize_resolution", "std_m": "localize_std_m", "std_rad": "localize_std_rad",
              "max_std_m": "localize_max_std_m", "max_std_rad": "localize_max_std_rad",
              "max_distance_m": "max_marker_distance_m", "turn_body": "look_behind",
              "max_frames": "localize_max_frames"}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> "LocalizeSettings":
        kw: dict[str, Any] = {}
        for f in fields(cls):
            key = cls.PARAMS.get(f.name)
            if key is not None and key in params:
                kw[f.name] = type(getattr(cls, f.name))(params[key])
        return cls(**kw)


@dataclass
class PoseEstimate:
    """What a localization gives: the fused pose (map frame) and its uncertainty (1 sigma), whether a
    landmark fix entered it, the codes used and what it cost."""

    x: float
    y: float
    theta: float
    std_m: float  # position, along the worst direction
    std_rad: float
    cov: list[list[float]]  # 3x3 covariance of (x, y, theta)
    fixed: bool  # False: no usable fix, the pose is the odometry's prediction
    markers: list[str] = field(default_factory=list)
    fix_std_m: float | None = None  # the fix's own std before fusion
    frames: int = 0  # frames captured by this localization
    frames_without_code: int = 0  # ... in which no known code was found
    turned_rad: float = 0.0  # the body turn it made to see codes
    # True: the codes seen disagree with each other or with the estimate and it cannot tell which is
    # right (a label moved since the map was made?): no fix entered, the pose is the prediction
    unsure: bool = False
    unsure_why: str = ""
    dropped: list[str] = field(default_factory=list)  # codes seen but left out: they disagreed with the rest

    @property
    def pose(self) -> Pose2D:
        """The pose as the planner and the robot API take it."""
        return Pose2D(x=self.x, y=self.y, theta=self.theta)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class HeadCamera:
    """The localization camera: intrinsics at its resolution and where it sits on the robot at head yaw
    0 (the head turns it about the neck's vertical axis, at `axis` in the base frame)."""

    K: np.ndarray
    width: int
    height: int
    robot_from_cam0: np.ndarray  # camera optical frame -> robot base, head yaw 0
    axis: tuple[float, float]
    limit: float  # head yaw reach, rad

    def cam_from_robot(self, yaw: float) -> np.ndarray:
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.eye(4)
        R[:2, :2] = [[c, -s], [s, c]]
        ax = np.eye(4)
        ax[:2, 3] = self.axis
        back = np.eye(4)
        back[:2, 3] = [-self.axis[0], -self.axis[1]]
        return np.linalg.inv(ax @ R @ back @ self.robot_from_cam0)


DOORWAY_M = 0.12  # a sight line crosses a wall within this of a doorway's line: through the doorway


def in_sight(p: Sequence[float] | np.ndarray, q: Sequence[float] | np.ndarray, rooms: Sequence[RoomSpec],
             doors: Iterable[DoorwaySpec], end_m: float = 0.1) -> bool:
    """Whether the walls leave the segment from p to the code at q (on a wall) free: every point of it
    inside a room's rectangle or in a doorway (a door's closed line: the door may still be shut). Without
    rooms in the home description, everything is in sight."""
    if not rooms:
        return True
    p, q = np.asarray(p[:2], float), np.asarray(q[:2], float)
    d = float(np.linalg.norm(q - p))
    t = np.linspace(0.0, max(0.0, 1.0 - end_m / max(d, 1e-6)), max(2, int(d / 0.05)))
    pts = p + t[:, None] * (q - p)
    R = np.array([r.rect for r in rooms], float)
    inside = ((pts[:, None, 0] >= R[:, 0]) & (pts[:, None, 0] <= R[:, 2])
              & (pts[:, None, 1] >= R[:, 1]) & (pts[:, None, 1] <= R[:, 3])).any(1)
    out = pts[~inside]
    if not len(out):
        return True
    near = np.zeros(len(out), bool)
    for door in doors:
        a = np.asarray(door.door.hinge, float)
        yaw = math.radians(door.door.closed_yaw_deg)
        ab = door.door.width_m * np.array([math.cos(yaw), math.sin(yaw)])
        s = np.clip(((out - a) @ ab) / (ab @ ab), 0.0, 1.0)
        near |= np.linalg.norm(out - (a + s[:, None] * ab), axis=1) <= DOORWAY_M
    return bool(near.all())


def candidates(pose: Sequence[float], landmarks: Mapping[str, LandmarkSpec], rooms: Sequence[RoomSpec],
               camera: HeadCamera, settings: LocalizeSettings, doors: Iterable[DoorwaySpec] = ()
               ) -> dict[str, LandmarkSpec]:
    """The landmarks that could be seen from `pose` with some head angle: in sight (walls hide codes
    of other rooms but through a doorway), near enough to decode at their own printed size and not
    seen too obliquely."""
    x, y, _ = pose
    f = float(camera.K[1, 1])
    out: dict[str, LandmarkSpec] = {}
    for text, lm in landmarks.items():
        d = math.hypot(lm.x - x, lm.y - y)
        if d > settings.max_distance_m or f * lm.size_m / max(d, 1e-6) < settings.min_code_px:
            continue
        off = math.atan2(y - lm.y, x - lm.x) - lm.yaw
        if abs(math.remainder(off, math.tau)) > math.radians(settings.max_view_deg):
            continue
        if in_sight((x, y), (lm.x, lm.y), rooms, doors):
            out[text] = lm
    return out


def views_at(pose: Sequence[float], yaw: float, landmarks: Mapping[str, LandmarkSpec], camera: HeadCamera,
             margin_px: float) -> list[tuple[str, View]]:
    """The codes wholly inside the frame (by `margin_px` from its edges) at head yaw `yaw`."""
    texts = list(landmarks)
    seen, _ = in_frame(pose, np.array([yaw]), [landmarks[t] for t in texts], camera, margin_px)
    cam = camera.cam_from_robot(yaw)
    return [(t, View(corners_world(landmarks[t]), camera.K, cam)) for t, ok in zip(texts, seen[0]) if ok]


def in_frame(pose: Sequence[float], yaws: np.ndarray, landmarks: Sequence[LandmarkSpec], camera: HeadCamera,
             margin_px: float) -> tuple[np.ndarray, np.ndarray]:
    """For every head yaw and landmark: whether its 4 corners fall inside the frame (by `margin_px`
    from the sides, half that from top and bottom), and the information (3x3, on x, y, theta) its
    corners would give of the pose (their pixel noise, PIXEL_NOISE; the analytic Jacobian of the
    projection). Shapes (Y, L) and (Y, L, 3, 3)."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    d = np.stack([corners_world(lm) for lm in landmarks]) - [x, y, 0.0]  # (L, 4, 3)
    pr = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], -1)
    dpr = np.zeros(pr.shape + (3,))  # d(robot-frame point)/d(x, y, theta)
    dpr[..., 0, 0], dpr[..., 1, 0] = -c, s
    dpr[..., 0, 1], dpr[..., 1, 1] = -s, -c
    dpr[..., 0, 2], dpr[..., 1, 2] = pr[..., 1], -pr[..., 0]
    T = np.stack([camera.cam_from_robot(float(a)) for a in yaws])  # (Y, 4, 4)
    R, t = T[:, :3, :3], T[:, :3, 3]
    pc = np.einsum("yij,lkj->ylki", R, pr) + t[:, None, None, :]  # (Y, L, 4, 3)
    dpc = np.einsum("yij,lkjq->ylkiq", R, dpr)
    Z = np.maximum(pc[..., 2], 1e-3)
    K = camera.K
    u = K[0, 0] * pc[..., 0] / Z + K[0, 2]
    v = K[1, 1] * pc[..., 1] / Z + K[1, 2]
    inside = ((pc[..., 2] > 0.3) & (u >= margin_px) & (u <= camera.width - margin_px)
              & (v >= margin_px / 2) & (v <= camera.height - margin_px / 2)).all(-1)
    Ju = K[0, 0] * (dpc[..., 0, :] - (pc[..., 0] / Z)[..., None] * dpc[..., 2, :]) / Z[..., None]
    Jv = K[1, 1] * (dpc[..., 1, :] - (pc[..., 1] / Z)[..., None] * dpc[..., 2, :]) / Z[..., None]
    J = np.stack([Ju, Jv], -2)  # (Y, L, 4, 2, 3)
    info = np.einsum("ylkaq,ylkar->ylqr", J, J) / PIXEL_NOISE ** 2
    return inside, info


@dataclass
class Look:
    yaw: float
    codes: list[str]
    predicted_std_m: float  # of the fix after this frame and the ones before it
    predicted_std_rad: float
    beside: bool = False  # a look beside an empty one, the same codes sought where the aim may have put them


def looks_beside(look: Look, bearing_std: float, code_half: float, camera: HeadCamera, frames_left: int) -> list[Look]:
    """Looks to either side of `look` whose frame held none of its codes, when the pose's uncertainty
    could have put them outside the frame: the bearing's 2 sigma (`bearing_std`, rad) beyond what the
    frame holds of a code `code_half` rad wide each side of its centre. Each frame holds a code within
    `usable` of its centre; the looks step 1.6 usable apart (they overlap a little), nearest first,
    within the head's reach, as many as `frames_left`. [] when the aim was certain enough: then the
    codes are hidden (by what the map does not know), and looking beside would not show them."""
    half_fov = math.atan(camera.width / 2 / float(camera.K[0, 0]))
    usable = max(half_fov - code_half, 0.1)
    reach = 2 * bearing_std
    if look.beside or reach <= usable:
        return []
    out: list[Look] = []
    k = 1
    while k * 1.6 * usable - usable < reach and len(out) < frames_left:
        for sign in (1, -1):
            yaw = look.yaw + sign * k * 1.6 * usable
            if abs(yaw) <= camera.limit and len(out) < frames_left:
                out.append(Look(yaw, list(look.codes), look.predicted_std_m, look.predicted_std_rad, beside=True))
        k += 1
    return out


def plan_looks(pose: Iterable[float], std_m: float, std_rad: float, landmarks: Mapping[str, LandmarkSpec],
               rooms: Sequence[RoomSpec], camera: HeadCamera, settings: LocalizeSettings,
               seen: np.ndarray | None = None, seen_codes: Iterable[str] = (), current_yaw: float = 0.0,
               doors: Iterable[DoorwaySpec] = (), missed: Collection[str] = ()) -> list[Look]:
    """Head angles to capture at, in order: each the one whose codes add most to what the frames before
    it (and `seen`, the information of the codes already found) tell of the pose, until the predicted
    fix is certain enough or `max_frames`; a look must show a code not planned or seen yet. Margins
    keep the codes inside the frame for the pose's uncertainty. `missed`: codes expected in a frame of
    this localization that held none (hidden by something the map does not know): not expected again."""
    pose = tuple(float(v) for v in pose)
    near = {t: lm for t, lm in candidates(pose, landmarks, rooms, camera, settings, doors).items() if t not in missed}
    if not near:
        return []
    texts = list(near)
    nearest = min(math.hypot(lm.x - pose[0], lm.y - pose[1]) for lm in near.values())
    margin = min(float(camera.K[0, 0]) * (2 * std_rad + 2 * std_m / max(nearest, 0.5)) + 8.0, camera.width / 4)
    yaws = np.linspace(-camera.limit, camera.limit, int(round(2 * camera.limit / YAW_STEP)) + 1)
    inside, infos = in_frame(pose, yaws, [near[t] for t in texts], camera, margin)
    options = [(float(yaw), [t for t, ok in zip(texts, row) if ok], infos[i][row].sum(0))
               for i, (yaw, row) in enumerate(zip(yaws, inside)) if row.any()]
    info = np.array(seen, float) if seen is not None else np.zeros((3, 3))
    known = set(seen_codes)
    plan: list[Look] = []
    while options and len(plan) < settings.max_frames:
        def score(opt: tuple[float, list[str], np.ndarray]) -> tuple[float, float]:
            s_m, s_r = std_from_information(info + opt[2])
            return (s_m + 0.5 * s_r, abs(opt[0] - current_yaw))
        fresh = [o for o in options if set(o[1]) - known]
        if not fresh:
            break
        best = min(fresh, key=score)
        info = info + best[2]
        known |= set(best[1])
        s_m, s_r = std_from_information(info)
        plan.append(Look(best[0], best[1], s_m, s_r))
        current_yaw = best[0]
        if s_m <= settings.std_m and s_r <= settings.std_rad:
            break
    return plan


def predicted(plan: list[Look]) -> tuple[float, float]:
    return (plan[-1].predicted_std_m, plan[-1].predicted_std_rad) if plan else (math.inf, math.inf)


@dataclass
class Verdict:
    """What `Localizer.judge` makes of a fix: the one to fuse (None: none), through which gate (None: taken
    as it is), the codes left out and, when it cannot tell, why it is unsure."""

    fix: Localization | None
    gate: float | None = CHI2_3DOF_99
    dropped: list[str] = field(default_factory=list)
    unsure: str = ""


def _within(found: Localization | None, std_m: float, std_rad: float) -> bool:
    """A fix with a pose, its position and heading no less certain than std_m / std_rad (a heading off by
    0.01 rad puts the end of a 1 m leg 1 cm off the path)."""
    return bool(found is not None and found.found and found.pose is not None and found.std_m is not None
                and found.std_theta_rad is not None and found.std_m <= std_m and found.std_theta_rad <= std_rad)


def _usable(found: Localization) -> bool:
    """A fix at all: no less certain than FUSE_MAX_STD_M/RAD."""
    return _within(found, FUSE_MAX_STD_M, FUSE_MAX_STD_RAD)


def _fixes_agree(a: Localization, b: Localization) -> bool:
    """Whether two fixes of the same moment agree within their (floored) uncertainties (99 %)."""
    za, zb = np.asarray(_z(a)), np.asarray(_z(b))
    d = za - zb
    d[2] = math.remainder(float(d[2]), math.tau)
    return float(d @ np.linalg.solve(_R(a) + _R(b), d)) <= CHI2_3DOF_99


def _floored(found: Localization) -> tuple[float, float]:
    return max(cast(float, found.std_m), FIX_FLOOR_M), max(cast(float, found.std_theta_rad), FIX_FLOOR_RAD)


def _z(found: Localization) -> tuple[float, float, float]:
    p = cast(Pose2D, found.pose)
    return p.x, p.y, p.theta


def _R(found: Localization) -> np.ndarray:
    s_m, s_rad = _floored(found)
    return np.diag([s_m ** 2, s_m ** 2, s_rad ** 2])


_L = TypeVar("_L", bound="Localizer")
_T = TypeVar("_T")


def noting_failure(step: Callable[[_L, dict[str, Any]], Awaitable[_T]]
                   ) -> Callable[[_L, dict[str, Any]], Coroutine[Any, Any, _T]]:
    """A localization step that, when a request fails, leaves why in memory["error"] (a RApp may say
    it to its user) and raises."""

    @functools.wraps(step)
    async def run(self: _L, memory: dict[str, Any]) -> _T:
        try:
            return await step(self, memory)
        except RequestError as e:
            memory["error"] = f"(localization failed: {e.reason})"
            raise

    return run


class Localizer:
    """A task's localization: the pose EKF, the landmark map and the frames' statistics. `localize()`
    runs it once; `build(name)` gives it as a sub-FSM of the task's own FSM (l1_prepare, l2_turn_head,
    l3_capture, l4_detect, l6_turn_around, l5_set_pose), leaving a PoseEstimate in memory["estimate"].
    Tell it the base's motions the task commands (`moved`) so that the filter knows how far it went."""

    def __init__(self, task: LocalizingTask, settings: LocalizeSettings | None = None, home: HomeInfo | None = None):
        self.task = task
        self.settings = settings or LocalizeSettings.from_params(getattr(task, "params", {}))
        self.home = home  # ontology.services.home.HomeInfo; fetched with home_get_info when None
        self.head: Head | None = None
        self.camera: HeadCamera | None = None
        self.intrinsics: dict[str, float] | None = None
        self.ekf: PoseEKF | None = None
        self.odom_ref: tuple[float, float, float] | None = None  # the robot's odometry pose the filter matched last
        self.travelled = self.turned = 0.0  # motion since then (m, rad), as commanded
        self.history: list[PoseEstimate] = []  # every localization's result
        # labels a fix left out once (they disagreed with the others: moved since the map was made?): a later
        # fix that leans on one is weighed against the prediction, not taken as the codes' word (judge)
        self.suspect: set[str] = set()
        self.state: dict[str, Any] = {}  # the localization running now (its own, not the task's memory)

    # -- statistics --------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Localizations, frames captured and frames without a code, over the task's run."""
        frames = sum(e.frames for e in self.history)
        empty = sum(e.frames_without_code for e in self.history)
        n = len(self.history)
        return {"localizations": n, "fixed": sum(e.fixed for e in self.history), "frames": frames,
                "frames_without_code": empty, "frames_per_localization": round(frames / n, 2) if n else None,
                "no_code_share": round(empty / frames, 3) if frames else None,
                "unsure": sum(e.unsure for e in self.history),
                "codes_dropped": sum(len(e.dropped) for e in self.history)}

    # -- the pose filter ---------------------------------------------------------------------
    def robot_type(self) -> str:
        robot_type: str = self.task.robot_info.robot_type  # ontology.spawn.RobotInfo's
        return robot_type

    def odometry_model(self) -> OdometryModel:
        return ODOMETRY.get(self.robot_type(), ODOMETRY["nao"])

    def moved(self, distance: float = 0.0, rotation: float = 0.0) -> None:
        """The task moved the base (m driven, rad turned): the odometry error grows with it."""
        self.travelled += abs(distance)
        self.turned += abs(rotation)

    async def track(self) -> PoseEKF:
        """Bring the filter up to the robot's odometry now (the first time: start it there)."""
        p = await self.task.robot.get_global_pose()
        odom = (p.x, p.y, p.theta)
        if self.ekf is None:
            self.ekf = PoseEKF(odom, START_STD_M, START_STD_RAD)
        else:
            odom_ref = cast("tuple[float, float, float]", self.odom_ref)  # set with the filter
            self.ekf.predict_between(odom_ref, odom, self.odometry_model(), travelled_m=self.travelled,
                                     turned_rad=self.turned)
        self.odom_ref, self.travelled, self.turned = odom, 0.0, 0.0
        return self.ekf

    def fix_predicted(self, pose: Sequence[float]) -> tuple[float, float]:
        """(std m, std rad) of the fix the head alone could take at `pose` (x, y, theta, map frame), by the
        landmark map and the filter's uncertainty now; inf before the first localization set the camera
        up, or where no code is in reach. numpy: call it off the event loop."""
        home, camera, ekf = self.home, self.camera, self.ekf
        if home is None or camera is None or ekf is None:
            return math.inf, math.inf
        return predicted(plan_looks(pose, ekf.std_m, ekf.std_rad, home.landmarks, home.rooms, camera, self.settings,
                                    doors=home.doors))

    def fixable(self, pose: Sequence[float], slack: float = 1.0) -> bool:
        """Whether the head alone could fix the pose at `pose` as certainly as a fix is trusted (max_std_m/rad),
        or `slack` times less certainly (a fix the filter weighs against its prediction)."""
        s_m, s_rad = self.fix_predicted(pose)
        return s_m <= slack * self.settings.max_std_m and s_rad <= slack * self.settings.max_std_rad

    def position_std(self) -> float:
        """The pose filter's position std (m) now; 0 before it starts (the plan monitor's "localized")."""
        return self.ekf.std_m if self.ekf is not None else 0.0

    def leg_length(self, longest: float, cross_track_std_m: float, shortest: float = 0.3) -> float:
        """The longest leg (at most `longest`) whose predicted sideways error stays within
        `cross_track_std_m` (one sigma) by the filter's covariance and the odometry's error model."""
        ekf, model = self.ekf, self.odometry_model()
        if ekf is None or ekf.cross_track_std(longest, model) <= cross_track_std_m:
            return longest
        lo, hi = shortest, longest
        for _ in range(20):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if ekf.cross_track_std(mid, model) <= cross_track_std_m else (lo, mid)
        return lo

    # -- one call ----------------------------------------------------------------------------
    async def localize(self) -> PoseEstimate:
        """Localize once (the sub-FSM run on its own); RuntimeError saying why when a request failed
        (the robot, the Platform or the Cloud Agent refused or did not answer)."""
        runtime = self.task.runtime
        memory: dict[str, Any] = {}
        outcome = await self.build().run(Context(agent=runtime, memory=memory, tracer=getattr(runtime, "tracer", None),
                                                 pause=getattr(runtime, "pause", None)))
        if not outcome.ok:  # a failed request left "(localization failed: why)"
            raise RuntimeError(memory["error"].strip("()") if "error" in memory else
                               f"localization failed: {outcome.reason}")
        estimate: PoseEstimate = memory["estimate"]
        return estimate

    # -- the sub-FSM -------------------------------------------------------------------------
    def build(self, name: str = "localize") -> FSM:
        fsm = FSM(name, initial="l1_prepare")
        fsm.add_state("l1_prepare", Step(self.prepare))
        fsm.add_state("l2_turn_head", Step(self.turn_head))
        fsm.add_state("l3_capture", Step(self.capture))
        fsm.add_state("l4_detect", Step(self.detect))
        fsm.add_state("l5_set_pose", Step(self.set_pose), final=True)
        fsm.add_state("l6_turn_around", Step(self.turn_around))
        fsm.add_transition("l1_prepare", "l2_turn_head")
        fsm.add_transition("l2_turn_head", "l3_capture", when=lambda m, o: o.value == "look")
        # nothing more to look at from here: turn the body toward the codes (once), else fuse what was found
        fsm.add_transition("l2_turn_head", "l6_turn_around", when=lambda m, o: o.value == "turn")
        fsm.add_transition("l2_turn_head", "l5_set_pose", when=lambda m, o: o.value == "done")
        fsm.add_transition("l6_turn_around", "l2_turn_head")
        fsm.add_transition("l3_capture", "l4_detect")
        fsm.add_transition("l4_detect", "l5_set_pose", when=lambda m, o: o.value)
        fsm.add_transition("l4_detect", "l2_turn_head", when=lambda m, o: not o.value)
        return fsm

    async def _home(self) -> HomeInfo:
        if self.home is None:
            self.home = await self.task.platform.home_get_info(home_id=str(self.task.params.get("home", "home")))
        return self.home

    async def _setup(self) -> None:
        robot = self.task.robot
        names = (await robot.get_joint_angles()).joints
        self.head = next(h for key, h in HEADS.items() if key in names)
        info = await robot.get_camera_info(resolution=self.settings.resolution)
        K = np.asarray(info.K, float)
        self.intrinsics = dict(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2])
        await self._head_to(0.0)
        cam = np.asarray((await robot.get_transform(chain="camera", space="robot")).matrix, float)
        neck = np.asarray((await robot.get_transform(chain="neck", space="robot")).matrix, float)
        w, h = (int(v) for v in self.settings.resolution.lower().split("x"))
        self.camera = HeadCamera(K, w, h, cam, (float(neck[0, 3]), float(neck[1, 3])), self.head["limit"])

    async def _head_to(self, yaw: float) -> None:
        head = cast(Head, self.head)  # _setup's, before any head motion
        await self.task.robot.move_joint(joints=[head["yaw"], head["pitch"]],
                                         angles=[yaw, head["tilt"]], speed=0.8)

    def _belief(self) -> tuple[tuple[float, float, float], float, float]:
        """The pose to plan from and its uncertainty: this localization's fix once it is better than the filter's."""
        found, ekf = self.state.get("localization"), self.ekf
        if ekf is None:  # what reading its pose would have raised: prepare() starts the filter (track)
            raise AttributeError("the pose filter has not started")
        if (found is not None and found.found and found.std_m is not None and found.std_theta_rad is not None
                and math.isfinite(found.std_m) and found.std_m < ekf.std_m):
            p = found.pose
            return (p.x, p.y, p.theta), found.std_m, min(found.std_theta_rad, ekf.std_rad)
        return ekf.pose, ekf.std_m, ekf.std_rad

    def _plan(self, pose: tuple[float, float, float] | None = None) -> list[Look]:
        belief, std_m, std_rad = self._belief()
        pose = pose or belief
        home = cast(HomeInfo, self.home)  # prepare() fetched it
        seen = [o for o in self.state["observations"]]
        seen_info = information(pose, observed_views(seen, home.landmarks)) if seen else None
        if self.state["frames"] >= self.settings.max_frames:
            return []
        camera = cast(HeadCamera, self.camera)  # _setup's
        return plan_looks(pose, std_m, std_rad, home.landmarks, home.rooms, camera, self.settings,
                          seen=seen_info, seen_codes={o.text for o in seen}, current_yaw=self.state.get("yaw", 0.0),
                          doors=home.doors, missed=self.state["missed"])

    def _best_turn(self, exclude: Collection[str] = ()) -> float | None:
        """The smallest body turn after which the head could fix the pose (or the best fix, when none
        can make it certain) by codes other than `exclude`; None when no turn shows a code."""
        (x, y, th), std_m, std_rad = self._belief()
        home, camera = cast(HomeInfo, self.home), cast(HeadCamera, self.camera)  # prepare()'s
        best: tuple[float, float] | None = None
        for deg in TURNS_DEG:
            plan = plan_looks((x, y, th + math.radians(deg)), std_m, std_rad + 0.05, home.landmarks,
                              home.rooms, camera, self.settings, doors=home.doors,
                              missed=set(self.state["missed"]) | set(exclude))
            s = predicted(plan)
            if not plan:
                continue
            if s[0] <= self.settings.std_m and s[1] <= self.settings.std_rad:
                return math.radians(deg)
            if best is None or s[0] < best[1]:
                best = (math.radians(deg), s[0])
        return best[0] if best is not None and best[1] <= self.settings.max_std_m else None

    @noting_failure
    async def prepare(self, memory: dict[str, Any]) -> None:
        await self._home()
        if self.camera is None:
            await self._setup()
        self.state = dict(observations=[], localization=None, prior=None, frames=0, empty=0, turned=0.0, yaw=0.0,
                          turn=None, turn_done=False, missed=set(), look=None)
        await self.track()
        self.state["looks"] = await asyncio.to_thread(self._plan)  # numpy: off the event loop
        s = predicted(self.state["looks"])
        if self.settings.turn_body and not (s[0] <= self.settings.std_m and s[1] <= self.settings.std_rad):
            turn = await asyncio.to_thread(self._best_turn)
            if turn is not None and (not self.state["looks"] or s[0] > self.settings.max_std_m):
                self.state["looks"], self.state["turn"] = [], turn  # nothing worth a frame from here: turn first

    @noting_failure
    async def turn_head(self, memory: dict[str, Any]) -> str:
        """The next planned head angle ("look"); "turn" when none is left but a body turn would show
        codes, "done" when nothing is left to try."""
        if self.state["frames"] >= self.settings.max_frames:
            return "done"
        if not self.state["looks"]:
            return "turn" if self.state["turn"] is not None else "done"
        look = self.state["looks"].pop(0)
        self.state["yaw"], self.state["look"] = look.yaw, look
        await self._head_to(look.yaw)
        return "look"

    @noting_failure
    async def turn_around(self, memory: dict[str, Any]) -> None:
        """No certain fix within the head's reach: turn the body toward the codes and plan again (codes
        seen before the turn are dropped: their camera-to-robot transforms no longer hold)."""
        turn, self.state["turn"] = self.state["turn"], None
        await self.task.robot.move_to(x=0.0, y=0.0, theta=turn, _timeout=60.0)
        self.moved(rotation=turn)
        self.state["turned"] += abs(turn)
        self.state["turn_done"] = True
        self.state.update(observations=[], localization=None, prior=None, yaw=0.0)
        await self.track()
        self.state["looks"] = await asyncio.to_thread(self._plan)

    @noting_failure
    async def capture(self, memory: dict[str, Any]) -> None:
        robot = self.task.robot
        self.state["frame"] = await robot.capture_image(resolution=self.settings.resolution)
        self.state["camera_to_robot"] = (await robot.get_transform(chain="camera", space="robot")).matrix
        self.state["frames"] += 1

    @noting_failure
    async def detect(self, memory: dict[str, Any]) -> bool:
        """Landmarks in this frame (on the Cloud Agent), then the pose from every code seen so far;
        True when that pose is certain enough to stop looking. Otherwise the looks left are planned
        again from what is known now."""
        home, cloud = cast(HomeInfo, self.home), self.task.cloud  # prepare() fetched the home
        reply: Observations | None
        try:
            reply = cast(Observations, await cloud.call(
                "observe", _ontology=LANDMARKS, image_b64=self.state.pop("frame").data_b64, camera=self.intrinsics,
                camera_to_robot=self.state["camera_to_robot"], landmarks=home.landmarks,
                max_distance_m=self.settings.max_distance_m, expect=self.state["look"].codes))
        except RequestFailed:  # a frame the Cloud Agent could not process: look elsewhere
            reply = None
        if reply is None or not reply.items:
            self.state["empty"] += 1
            look = self.state["look"]
            beside = self._looks_beside(look)
            if beside:  # the aim, not the code, may have been off: look to either side first
                self.state["looks"] = beside + [lk for lk in self.state["looks"] if not lk.beside]
                return False
            if look.beside and any(lk.beside for lk in self.state["looks"]):
                return False  # the other side next
            self.state["missed"] |= set(self.state["look"].codes)  # not expected again in this localization
            await asyncio.to_thread(self._replan)
            return False
        self.state["observations"].extend(reply.items)
        # codes the look expected that this frame did not show (too far, too oblique, covered): the same
        # look again would show the same, so they are not expected again in this localization
        self.state["missed"] |= set(self.state["look"].codes) - {o.text for o in reply.items}
        if self.state.get("prior") is None:
            self.state["prior"] = await self.task.robot.get_global_pose()
        found = await self._solve(self.state["observations"])
        self.state["localization"] = found
        if _within(found, self.settings.std_m, self.settings.std_rad) and self._corroborated(found):
            return True
        await asyncio.to_thread(self._replan)
        return False

    def _looks_beside(self, look: Look) -> list[Look]:
        """looks_beside for this localization: the codes' bearing uncertainty from the belief now."""
        (x, y, _), std_m, std_rad = self._belief()
        home, camera = cast(HomeInfo, self.home), cast(HeadCamera, self.camera)  # prepare()'s
        codes = [home.landmarks[t] for t in look.codes if t in home.landmarks]
        if not codes:
            return []
        nearest = min(max(math.hypot(lm.x - x, lm.y - y), 0.3) for lm in codes)
        code_half = max(math.atan(lm.size_m / 2 / max(math.hypot(lm.x - x, lm.y - y), 0.3)) for lm in codes)
        left = self.settings.max_frames - self.state["frames"]
        return looks_beside(look, std_rad + std_m / nearest, code_half, camera, left)

    def _replan(self) -> None:
        self.state["looks"] = self._plan()
        if (not self.state["looks"] and self.settings.turn_body and not self.state["turn_done"]
                and self.state["frames"] < self.settings.max_frames):
            found: Localization | None = self.state.get("localization")
            if found is None or not _within(found, self.settings.max_std_m, self.settings.max_std_rad):
                self.state["turn"] = self._best_turn()
            elif not self._corroborated(found):  # one code, nothing to check it by: look for others, once
                self.state["turn"] = self._best_turn(exclude=found.markers)

    def _corroborated(self, found: Localization) -> bool:
        """Whether the looking may stop at this fix: it rests on two codes or more (the Cloud Agent's fit
        leaves out one that disagrees), or the filter is certain enough to check it (CHECKABLE_STD_M) and
        it passes the filter's gate. A lone code the filter disagrees with may be a moved label or a right
        one after the odometry slipped (a rug): a second code tells which."""
        if len(found.markers) >= 2:
            return True
        ekf = self.ekf
        return ekf is not None and ekf.std_m <= CHECKABLE_STD_M and ekf.mahalanobis2(_z(found), _R(found)) <= CHI2_3DOF_99

    async def _share_fix(self, pose: Pose2D, std_m: float, std_rad: float) -> None:
        """The fix to the Core too (add_pose_fix), before the RApp sets its own pose: the Core's
        estimate (get_pose_estimate, paper 001's relative localization) is then QR-fused as well. A
        Core that refuses it (its own gate, or one without the action) leaves the RApp's filter as it is."""
        try:
            await self.task.robot.add_pose_fix(x=pose.x, y=pose.y, theta=pose.theta, std_m=std_m, std_rad=std_rad)
        except RequestError as e:
            self.task.log.debug("the Core did not take the fix: %s", e)

    async def _solve(self, observations: list[Any]) -> Localization:
        home = cast(HomeInfo, self.home)  # prepare() fetched it
        return cast(Localization, await self.task.cloud.call(
            "solve_pose", _ontology=LANDMARKS, observations=observations, landmarks=home.landmarks,
            prior=self.state["prior"].model_dump()))

    async def judge(self, ekf: PoseEKF, found: Localization) -> Verdict:
        """Which fix to fuse, checked for consistency. A fix from two or more codes that agree with each
        other (the Cloud Agent's fit left none out) is taken even against the prediction: the codes
        outvote a drifted filter, unless one of them was left out of a fix before (`suspect`: two labels
        moved alike agree with each other). A fix from one code, or one the Cloud Agent had to leave codes
        out of (they disagree: a label moved since the map was made, a bad corner), must agree with the
        prediction (Mahalanobis gate); otherwise the codes left out are solved on their own and their
        fix is taken if it agrees instead. A fix leaning on doubted codes that passes the gate is solved
        again without them: when that agrees with the prediction but not with the first, it is taken (a
        label moved a little still pulls a fix). No fix agreeing, or the kept and the left-out codes both
        agreeing but not with each other: unsure, nothing is fused (the pose does not jump)."""
        seen = list(dict.fromkeys(o.text for o in self.state["observations"]))
        left_out = [t for t in seen if t not in found.markers]
        doubted = [t for t in found.markers if t in self.suspect]
        if len(found.markers) >= 2 and not left_out and not doubted:
            return Verdict(found, gate=None)
        options = [found]
        if left_out:
            alone = await self._solve([o for o in self.state["observations"] if o.text in left_out])
            if _usable(alone):
                options.append(alone)
        agree = [o for o in options if _usable(o) and ekf.mahalanobis2(_z(o), _R(o)) <= CHI2_3DOF_99]
        if doubted and len(doubted) < len(found.markers) and found in agree:
            # the doubted codes may pass the gate and still pull the fix (a label moved a few cm): the fix
            # without them, when it agrees with the prediction but not with the fix that has them, is taken
            # and they stay doubted; when both fixes agree, the doubted codes were right after all
            rest = await self._solve([o for o in self.state["observations"]
                                      if o.text in found.markers and o.text not in doubted])
            if (_usable(rest) and ekf.mahalanobis2(_z(rest), _R(rest)) <= CHI2_3DOF_99
                    and not _fixes_agree(found, rest)):
                return Verdict(rest, gate=CHI2_3DOF_99, dropped=[t for t in seen if t not in rest.markers])
        if len(agree) == 1:
            fix = agree[0]
            return Verdict(fix, gate=CHI2_3DOF_99, dropped=[t for t in seen if t not in fix.markers])
        if not agree and left_out:
            why = "the codes disagree with each other and with the estimate"
        elif not agree and len(found.markers) >= 2:
            why = (f"the codes {', '.join(found.markers)} disagree with the estimate, and {', '.join(doubted)} "
                   "disagreed with other codes before")
        elif not agree:
            why = f"the code {found.markers[0]} disagrees with the estimate"
        else:
            why = f"the codes {', '.join(found.markers)} and {', '.join(left_out)} disagree and either fits the estimate"
        return Verdict(None, unsure=why, dropped=left_out)

    @noting_failure
    async def set_pose(self, memory: dict[str, Any]) -> None:
        """Fuse the fix into the filter and set the filter's pose on the robot. A fix certain enough
        (max_std_m/rad) or a less certain one (up to FUSE_MAX_STD_M/RAD) is checked (`judge`), then
        fused, through the Mahalanobis gate unless its codes agree with each other; when the codes
        disagree and it cannot tell which are right, the estimate says so (`unsure`) and the odometry's
        prediction stays, as without a fix."""
        ekf = await self.track()
        found = self.state.get("localization")
        fixed = False
        markers: list[str] = []  # the fix's, once fused
        fix_std_m: float | None = None
        verdict = Verdict(None)
        if (found is not None and not found.found and found.method == "single-too-far" and found.pose is not None
                and found.std_m is not None and found.std_theta_rad is not None
                and ekf.std_m >= LOST_FACTOR * found.std_m and ekf.std_rad >= found.std_theta_rad):
            # better than nothing by far (a start pose hardly trusted): weighed against the prediction
            verdict = Verdict(found.model_copy(update={"found": True}), gate=CHI2_3DOF_99)
        elif found is not None and _usable(found):
            certain = _within(found, self.settings.max_std_m, self.settings.max_std_rad)
            verdict = await self.judge(ekf, found)
            if verdict.fix is not None and not certain and verdict.gate is None:
                verdict.gate = CHI2_3DOF_99  # agreeing codes, but not certain: weighed against the prediction
        fix = verdict.fix
        if fix is not None:
            if ekf.update(_z(fix), R=_R(fix), gate=verdict.gate):
                # the codes this fix left out disagreed with codes that fit the estimate: doubted from now on;
                # a doubted code in a fix that passed the gate agreed after all (a bad frame, not a move)
                self.suspect = (self.suspect - set(fix.markers)) | set(verdict.dropped)
                s_m, s_rad = _floored(fix)
                p = cast(Pose2D, fix.pose)
                await self._share_fix(p, s_m, s_rad)
                x, y, theta = ekf.pose
                await self.task.robot.set_global_pose(x=x, y=y, theta=theta)
                self.odom_ref = ekf.pose
                fixed, markers, fix_std_m = True, list(fix.markers), fix.std_m
        if verdict.unsure:
            self.task.log.info("localization unsure: %s; keeping the odometry's pose", verdict.unsure)
        x, y, theta = ekf.pose
        estimate = PoseEstimate(x=x, y=y, theta=theta, std_m=ekf.std_m, std_rad=ekf.std_rad, cov=ekf.P.tolist(),
                                fixed=fixed, markers=markers, fix_std_m=fix_std_m, frames=self.state["frames"],
                                frames_without_code=self.state["empty"], turned_rad=self.state["turned"],
                                unsure=bool(verdict.unsure), unsure_why=verdict.unsure, dropped=verdict.dropped)
        self.history.append(estimate)
        memory["estimate"] = estimate
        head = cast(Head, self.head)  # _setup's
        await self.task.robot.move_joint(joints=[head["yaw"], head["pitch"]], angles=[0.0, 0.0], speed=0.8)
