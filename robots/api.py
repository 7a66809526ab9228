"""Async robot API: one RobotAPI per robot; every method takes the request model of ontology.robot and
returns its reply model, so the Core can dispatch generically: ``await getattr(api, req.action_name)(req)``.

Nothing here blocks the event loop: pybullet work runs in the world's worker thread, image encoding in
the default executor, motions complete in simulation time. Ground truth is NOT reachable from here
(use World.ground_truth() in tests and scoring)."""
from __future__ import annotations

import asyncio
import base64
import math
from functools import partial
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from hearing import tts
from hearing.errors import BadAudio
from hearing.wav import decode_wav, encode_wav, level_dbfs
from ontology.errors import ErrorCode
from ontology.registry import Done
from ontology.robot import (AUDIO_BUFFER_S, MAX_AUDIO_SECONDS, MAX_MICROPHONES, Audio, CameraInfo, CameraParams,
                            CaptureAudio, CaptureDepth, CaptureImage, ContactChange, Contacts, DepthImage, GetContacts, GetCameraInfo, GetGlobalPose, GetJointAngles, GetLaserScan, GetSonars,
                            GetTransform, Image, JointAngles, LaserScan,
                            LookAtPoint, MicrophoneEnergy, MicrophoneLevel, MoveAlongPath, MoveJoint, MoveStop, MoveTo,
                            MoveVel, PlayAudio, Pose2D, Rest, Say, SetCameraParam, SetCameraParams, SetGlobalPose,
                            SonarReading, TakePredefinedPosture, Transform, WordSpotted, WordSpotting)
from .controllers import GoToPose, JointMotion, LookAt, PathFollower, VelocityController
from .depth_png import encode_depth
from .errors import InvalidArgument, MotionInterrupted, UnsupportedOperation
from .loudspeaker import check_speech
from .microphones import AudioInput, spot_in_audio
from .receptors import Camera, encode_frame, parse_resolution
from .robot import Robot
from .sound import house_sound

if TYPE_CHECKING:
    from .world import World

MAX_DEPTH_PIXELS = 320 * 240
CAMERA_PARAM_NAMES = ("brightness", "contrast", "gain", "exposure", "auto_exposure")


class RobotAPI:
    def __init__(self, robot: Robot):
        self.robot = robot
        self.world = cast("World", robot.world)  # a Robot's surroundings are the World that added it
        self.house = house_sound(robot.world)
        self.audio_in = AudioInput(robot, self.house)

    # ------------------------------------------------------------------ helpers
    def _camera(self, name: str) -> Camera:
        cams = self.robot.cameras
        if not name:
            return next(iter(cams.values()))
        aliases = {"camera": next(iter(cams)), "main": next(iter(cams))}
        key = aliases.get(name.lower(), name)
        if key not in cams:
            raise InvalidArgument(f"unknown camera {name!r} on {self.robot.kind} (known: {', '.join(cams)})")
        return cams[key]

    async def _motion(self, slot: str, ctrl, joint_names: set[str] | None = None) -> Any:
        """Pre-empt conflicting motions of this robot, start `ctrl`, wait for it in simulation time."""
        r = self.robot
        for key, old in list(r.controllers.items()):
            if key == slot if joint_names is None else (
                    isinstance(old, JointMotion) and bool(old.joint_names & joint_names)):
                self._interrupt(key, f"{old.__class__.__name__} pre-empted by a newer command")
        key = slot if joint_names is None else f"joints:{id(ctrl)}"
        r.controllers[key] = ctrl
        fut = self.world.start(ctrl)
        if not ctrl.blocking:
            return None
        try:
            return await fut
        except asyncio.CancelledError:  # the request was cancelled: the motion stops with it
            if r.controllers.get(key) is ctrl:  # (not pre-empted already by a newer command)
                self._interrupt(key, f"{ctrl.__class__.__name__} cancelled")
            raise
        finally:
            if r.controllers.get(key) is ctrl:
                del r.controllers[key]

    # ------------------------------------------------------------------ robots.interface.RobotInterface
    @property
    def microphone(self):
        return self.robot.microphone

    def capabilities(self) -> frozenset[str]:
        r = self.robot
        have = {"speech": r.loudspeaker is not None, "microphone": r.microphone is not None,
                "camera": bool(r.cameras), "head": bool(r.spec.head_yaw), "sonars": bool(r.sonars),
                "laser": r.laser is not None, "depth": bool(r.depth_cameras), "bumpers": bool(r.spec.bumpers),
                "touch": bool(r.spec.touch_sensors)}
        return frozenset(k for k, v in have.items() if v)

    def moving_forward(self, min_speed: float = 0.02) -> bool:
        """A base motion is running and its last step drove forward (m/s above min_speed): what a
        forward-looking range sensor must watch. Turning on the spot is not moving forward."""
        ctrl = self.robot.controllers.get("base")
        return ctrl is not None and not ctrl.done and self.robot.base.command[0] > min_speed

    def protect(self, margin_m: float | None) -> None:
        self.robot.protection_m = margin_m  # read by the base controllers in the pybullet thread

    def odometry_counters(self) -> tuple[float, float]:
        odometry = self.robot.odometry  # two floats the pybullet thread adds to at each step
        return odometry.travelled, odometry.turned

    def loudspeaker_timing(self):
        return self.robot.loudspeaker  # robots/loudspeaker.py: what it played, in simulation time

    async def halt(self, reason: str) -> None:
        """The emergency stop: every running motion (base, head, joints) is interrupted and the
        loudspeaker falls silent (what it was saying is cut off)."""
        r = self.robot
        for key in list(r.controllers):
            self._interrupt(key, f"stopped by {reason}")
        if r.loudspeaker is not None:
            r.loudspeaker.silence(self.world.time)
        await self.world.sync()

    def _stop_base(self, reason: str) -> None:
        self._interrupt("base", f"base motion stopped by {reason}")

    def _interrupt(self, key: str, why: str) -> None:
        """The motion in controller slot `key` stops; whoever awaits it gets MotionInterrupted(why)."""
        ctrl = self.robot.controllers.pop(key, None)
        if ctrl is not None and not ctrl.done:
            ctrl.cancel(MotionInterrupted(f"{self.robot.name}: {why}"))
            self.world.keep_stepping()  # a walk stopped mid-step finishes it (mechanical drive)

    # ------------------------------------------------------------------ communication
    async def say(self, req: Say) -> Done:
        speaker = check_speech(self.robot)
        voice = tts.voice_for(req.language, req.voice)
        loop = asyncio.get_running_loop()
        pcm = await loop.run_in_executor(None, partial(tts.synthesize, req.text, voice, req.speed))
        await self.world.sleep(speaker.play(pcm, self.world.time, text=req.text))
        return Done()

    async def play_audio(self, req: PlayAudio) -> Done:
        speaker = check_speech(self.robot)
        try:
            data = base64.b64decode(req.data_b64, validate=True)
        except ValueError:
            raise BadAudio("play_audio: data_b64 is not base64", ErrorCode.MALFORMED) from None
        pcm, _ = decode_wav(data, max_seconds=60.0)
        await self.world.sleep(speaker.play(pcm, self.world.time))
        return Done()

    async def _record(self, seconds: float, rate: int = 16000, drive: bool = True, array: bool = False
                      ) -> tuple[float, np.ndarray]:
        """(start time, int16 samples) of the microphone over the next `seconds` of simulation time."""
        t0, pos = self.world.time, self.audio_in.position()
        await self.world.sleep(seconds, drive=drive)
        return t0, await self._heard(pos, t0, seconds, rate, array)

    async def _heard(self, pos, t0: float, seconds: float, rate: int, array: bool) -> np.ndarray:
        """The recording (mono, or (channels, n) with array), rendered in an executor."""
        if array:
            job = partial(self.audio_in.record_array, pos, self.robot.pose[2], t0, seconds)
        else:
            job = partial(self.audio_in.record, pos, t0, seconds, rate)
        return await asyncio.get_running_loop().run_in_executor(None, job)

    async def _record_since(self, since: float, seconds: float, rate: int, drive: bool, array: bool = False
                            ) -> tuple[float, np.ndarray]:
        """(start time, int16 samples) of the microphone from `since` (CaptureAudio.since): the sound is a
        function of simulation time, so the device's buffer is the house's sound of that past stretch
        (heard where the microphone is now)."""
        now = self.world.time
        if since > now + 1e-6:
            raise InvalidArgument(f"capture_audio since={since:.3f} s is later than the simulation time {now:.3f} s")
        t0 = max(since, now - AUDIO_BUFFER_S)
        if now < t0 + seconds - 1e-9:
            await self.world.sleep(t0 + seconds - now, drive=drive)
        t1 = min(max(self.world.time, t0 + seconds), t0 + MAX_AUDIO_SECONDS / (MAX_MICROPHONES if array else 1))
        # whole samples up to the world's time: the next `since` (stamp + samples / rate) is not later
        # than it (a half sample rounded up was: the next request, before the world moved, was refused)
        n = int((t1 - t0) * rate + 1e-6)
        return t0, await self._heard(self.audio_in.position(), t0, n / rate, rate, array)

    async def capture_audio(self, req: CaptureAudio) -> Audio:
        if req.since is not None:
            t0, pcm = await self._record_since(req.since, req.seconds, req.sample_rate, drive=not req.observe,
                                               array=req.array)
        else:
            t0, pcm = await self._record(req.seconds, req.sample_rate, drive=not req.observe, array=req.array)
        wav = encode_wav(pcm, req.sample_rate)
        mics = [tuple(m) for m in self.audio_in.microphones()] if req.array else []
        return Audio(sample_rate=req.sample_rate, seconds=pcm.shape[-1] / req.sample_rate,
                     data_b64=base64.b64encode(wav).decode(), stamp=t0, channels=1 if pcm.ndim == 1 else len(pcm),
                     microphones=mics)

    async def microphone_energy(self, req: MicrophoneEnergy) -> MicrophoneLevel:
        t0, pcm = await self._record(req.seconds)
        rms, peak = level_dbfs(pcm)
        return MicrophoneLevel(rms_dbfs=rms, peak_dbfs=peak, seconds=req.seconds, stamp=t0)

    async def word_spotting(self, req: WordSpotting) -> WordSpotted:
        """Typed utterances (wall clock) and, with req.audio, the room's sound (simulation time): the
        first word found either way; None when both have timed out."""
        if not req.words:
            raise InvalidArgument("word_spotting needs at least one word")
        listeners = [asyncio.ensure_future(self.robot.microphone.spot(req.words, req.timeout))]
        if req.audio:
            listeners.append(asyncio.ensure_future(spot_in_audio(self.audio_in, self.world, req.words, req.timeout)))
        try:
            pending = set(listeners)
            while pending:
                done, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                for task in done:
                    word, text = task.result()
                    if word is not None:
                        return WordSpotted(word=word, text=text)
            return WordSpotted()
        finally:
            for task in listeners:
                task.cancel()

    # ------------------------------------------------------------------ vision
    async def capture_array(self, camera: str = "", resolution: str = "320x240") -> np.ndarray:
        """RGB uint8 array (H, W, 3) with the camera parameters applied (no PNG encoding)."""
        cam = self._camera(camera)
        w, h = parse_resolution(resolution)
        return await self.world.capture(cam, w, h)

    async def capture_image(self, req: CaptureImage) -> Image:
        cam = self._camera(req.camera)
        stamp = self.world.time
        img = await self.capture_array(req.camera, req.resolution)
        loop = asyncio.get_running_loop()  # a noisy camera's frame is sent as JPEG (robots/receptors.py)
        encoding, data = await loop.run_in_executor(None, encode_frame, img, cam.noise is None)
        return Image(camera=cam.name, width=img.shape[1], height=img.shape[0], encoding=encoding,
                     data_b64=base64.b64encode(data).decode(), stamp=stamp)

    def _params(self, cam: Camera) -> CameraParams:
        p = cam.params
        return CameraParams(brightness=p.brightness, contrast=p.contrast, gain=p.gain, exposure=p.exposure,
                            auto_exposure=p.auto_exposure)

    async def set_camera_param(self, req: SetCameraParam) -> CameraParams:
        cam = self._camera(req.camera)
        if req.name not in CAMERA_PARAM_NAMES:
            raise InvalidArgument(f"unknown camera parameter {req.name!r} (known: {', '.join(CAMERA_PARAM_NAMES)})")
        value: Any = bool(req.value) if req.name == "auto_exposure" else float(req.value)
        if req.name in ("contrast", "gain", "exposure") and value <= 0:
            raise InvalidArgument(f"{req.name} must be > 0")
        cam.set_params(**{req.name: value})
        return self._params(cam)

    async def set_camera_params(self, req: SetCameraParams) -> CameraParams:
        cam = self._camera(req.camera)
        for n in ("contrast", "gain", "exposure"):
            v = getattr(req, n)
            if v is not None and v <= 0:
                raise InvalidArgument(f"{n} must be > 0")
        cam.set_params(brightness=req.brightness, contrast=req.contrast, gain=req.gain, exposure=req.exposure,
                       auto_exposure=req.auto_exposure)
        return self._params(cam)

    async def get_camera_info(self, req: GetCameraInfo) -> CameraInfo:
        cam = self._camera(req.camera)
        w, h = parse_resolution(req.resolution)
        K = cam.intrinsics(w, h)
        P = np.hstack([K, np.zeros((3, 1))])
        hf, vf = cam.fov(w, h)
        return CameraInfo(camera=cam.name, width=w, height=h, K=K.tolist(), P=P.tolist(),
                          hfov_deg=math.degrees(hf), vfov_deg=math.degrees(vf))

    # ------------------------------------------------------------------ navigation
    async def move_to(self, req: MoveTo) -> Done:
        await self._motion("base", GoToPose(self.robot, relative=(req.x, req.y, req.theta)))
        return Done()

    async def move_vel(self, req: MoveVel) -> Done:
        ctrl = VelocityController(self.robot, req.x, req.y, req.theta)  # raises on lateral diff-drive
        if ctrl.v == (0.0, 0.0, 0.0):
            return await self.move_stop(MoveStop())
        await self._motion("base", ctrl)
        return Done()

    async def move_stop(self, req: MoveStop) -> Done:
        self._stop_base("move_stop")
        await self.world.sync()  # the pybullet thread will not step the stopped motion any more
        return Done()

    async def move_along_path(self, req: MoveAlongPath) -> Done:
        if not req.poses:
            raise InvalidArgument("move_along_path needs at least one pose")
        await self._motion("base", PathFollower(self.robot, [(q.x, q.y, q.theta) for q in req.poses]))
        return Done()

    async def look_at_point(self, req: LookAtPoint) -> Done:
        s = self.robot.spec
        ctrl = LookAt(self.robot, (req.x, req.y, req.z), s.joint_speed)
        await self._motion("joints", ctrl, joint_names={s.head_yaw, s.head_pitch})
        return Done()

    async def get_global_pose(self, req: GetGlobalPose) -> Pose2D:
        x, y, th = self.robot.odometry.estimate
        return Pose2D(x=x, y=y, theta=th)

    async def set_global_pose(self, req: SetGlobalPose) -> Done:
        await self.world.run(self.robot.odometry.set, (req.x, req.y, req.theta))
        return Done()

    def _chain_pose(self, chain: str) -> np.ndarray:
        """World pose of a named frame (pybullet thread)."""
        r = self.robot
        c = chain.lower()
        if c in ("camera", "main") or c in r.cameras:
            # the robot's kinematics: not the walking torso's roll and bob, which the robot does not know
            return self._camera("" if c in ("camera", "main") else c).optical_pose(nominal=True)
        named = {"head": r.spec.head_pitch, "neck": r.spec.head_yaw}
        if c in named:
            j = named[c]
            return r.link_pose(r.link_of_joint(j))
        sensors = {s.name: s.spec.link for s in r.sonars}
        if r.laser:
            sensors["laser"] = r.laser.spec.link
        if c in r.depth_cameras:
            return r.depth_cameras[c].optical_pose()
        if c in sensors:
            return r.link_pose(sensors[c])
        if c in ("base", "base_link", "robot"):
            return r.base_in_world()
        known = ["camera", *r.cameras, *r.depth_cameras, "head", "neck", *sensors, "base"]
        raise InvalidArgument(f"unknown chain {chain!r} (known: {', '.join(known)})")

    async def get_transform(self, req: GetTransform) -> Transform:
        if req.space not in ("robot", "global"):
            raise InvalidArgument("space must be 'robot' or 'global'")

        def compute() -> np.ndarray:
            T = self.robot.in_base(self._chain_pose(req.chain))
            if req.space == "global":
                x, y, th = self.robot.odometry.estimate
                B = np.eye(4)
                B[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
                B[:2, 3] = [x, y]
                T = B @ T
            return T

        T = await self.world.run(compute)
        return Transform(chain=req.chain, space=req.space, matrix=T.tolist())

    async def move_joint(self, req: MoveJoint) -> Done:
        targets = self.robot.joints.targets(req.joints, req.angles)
        speed = self.robot.joints.speed(req.speed)
        await self._motion("joints", JointMotion(self.robot, targets, speed), joint_names=set(targets))
        return Done()

    async def get_joint_angles(self, req: GetJointAngles) -> JointAngles:
        names = req.joints or self.robot.joints.names
        for n in names:
            if n not in self.robot.joints.names:
                raise InvalidArgument(f"unknown joint {n!r}")
        return JointAngles(joints=list(names), angles=[self.robot.q[n] for n in names])

    async def take_predefined_posture(self, req: TakePredefinedPosture) -> Done:
        targets = self.robot.joints.posture(req.posture)
        speed = self.robot.joints.speed(req.speed)
        await self._motion("joints", JointMotion(self.robot, targets, speed), joint_names=set(targets))
        return Done()

    async def rest(self, req: Rest) -> Done:
        self._stop_base("rest")
        await self.take_predefined_posture(TakePredefinedPosture(posture=self.robot.spec.rest_posture, speed=0.5))
        return Done()

    # ------------------------------------------------------------------ sensors
    async def get_sonars(self, req: GetSonars) -> SonarReading:
        r = self.robot
        if not r.sonars:
            raise UnsupportedOperation(f"{r.kind} has no sonars (use get_laser_scan)")
        left, right, mount = await self.world.run(lambda: [*(s.read() for s in r.sonars),
                                                           r.sensor_mount(r.sonars[0].spec.link)])
        spec = r.sonars[0].spec
        return SonarReading(left=left, right=right, range_min=spec.range_min, range_max=spec.range_max,
                            mount_x=round(mount[0], 4), bearing=round(abs(mount[2]), 4))

    async def get_laser_scan(self, req: GetLaserScan) -> LaserScan:
        r = self.robot
        if r.laser is None:
            raise UnsupportedOperation(f"{r.kind} has no laser scanner (use get_sonars)")
        ranges, mount = await self.world.run(lambda: (r.laser.scan(), r.sensor_mount(r.laser.spec.link)))
        s = r.laser.spec
        return LaserScan(angle_min=s.angle_min, angle_max=s.angle_max,
                         angle_increment=(s.angle_max - s.angle_min) / (s.rays - 1), range_min=s.range_min,
                         range_max=s.range_max, ranges=[float(v) for v in ranges], mount_x=round(mount[0], 4))

    async def get_contacts(self, req: GetContacts) -> Contacts:
        r = self.robot
        if r.contacts is None:
            raise UnsupportedOperation(f"{r.kind} has no contact sensors (bumpers, touch)")
        last, pressed = r.contacts.last, dict(r.contacts.pressed)
        changes = [ContactChange(sensor=c.sensor, kind=c.kind, pressed=c.pressed, stamp=c.stamp, seq=c.seq)  # type: ignore[arg-type]
                   for c in r.contacts.after(req.after) if c.seq <= last]
        return Contacts(pressed=pressed, changes=changes, last=last, stamp=self.world.time)

    async def capture_depth(self, req: CaptureDepth) -> DepthImage:
        r = self.robot
        if not r.depth_cameras:
            raise UnsupportedOperation(f"{r.kind} has no depth camera")
        name = req.camera or next(iter(r.depth_cameras))
        cam = r.depth_cameras.get(name)
        if cam is None:
            raise InvalidArgument(f"unknown depth camera {req.camera!r} on {r.kind} (known: {', '.join(r.depth_cameras)})")
        w, h = parse_resolution(req.resolution)
        if w * h > MAX_DEPTH_PIXELS:  # a noisy VGA depth image's PNG is ~230 K base64 characters: not one message
            raise InvalidArgument(f"depth resolution {w}x{h} is larger than the Kinect's 320x240 mode")
        stamp = self.world.time
        mount = await self.world.run(lambda: r.in_base(cam.optical_pose()))
        z = await self.world.capture(cam, w, h)  # type: ignore[arg-type] - a DepthCamera renders as a Camera does
        data = await asyncio.get_running_loop().run_in_executor(None, encode_depth, z)
        return DepthImage(camera=name, width=w, height=h, data_b64=base64.b64encode(data).decode(), stamp=stamp,
                          range_min=cam.spec.range_min, range_max=cam.spec.range_max,
                          K=cam.intrinsics(w, h).tolist(), camera_to_robot=mount.tolist())

    # ------------------------------------------------------------------ generic dispatch
    async def handle(self, req) -> Any:
        """Dispatch any ontology.robot request model to its method."""
        return await getattr(self, req.action_name)(req)
