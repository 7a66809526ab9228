"""Simulated home world, NAO-like and Elektron-like robots, and their async robot API.

A house description (YAML, see robots/floorplan.py and robots/houses/) becomes a PyBullet world
(World), robots are added to it (Robot), and RobotAPI wraps one robot for the Core Agent: every method
takes an ontology.robot request model and returns its reply model. All pybullet calls of a world run
in one worker thread; motions complete in simulation time (rtf 0 = as fast as possible). Camera images
are rendered in up to two render processes that mirror the scene (robots/render_process.py), so a frame
neither holds this process's GIL nor delays stepping; World.from_file(..., render="inline") (or the
environment variable RAPP_ROBOTS_RENDER=inline) renders in the pybullet thread instead.

    import asyncio, math
    from ontology.robot import CaptureImage, LookAtPoint, MoveTo
    from robots import RobotAPI, World

    async def main():
        world = World.from_file("small", seed=1, overrides={"doors": {"d1": 45}, "lamps": {"l1": True}})
        nao = RobotAPI(world.add_robot("nao"))                 # start pose from the house file
        await nao.move_to(MoveTo(x=0.5, y=0.0, theta=math.pi / 2))
        await nao.look_at_point(LookAtPoint(x=0.4, y=3.6, z=1.4))   # global frame, uses the pose estimate
        img = await nao.capture_image(CaptureImage(resolution="320x240"))  # PNG, base64
        print(world.ground_truth())                            # true poses/doors/lamps: tests only
        world.close()
    asyncio.run(main())

Camera optical frame: x right, y down, z forward; get_camera_info gives K consistent with the render,
get_transform("camera") the optical frame in the robot base frame (base frame at the floor, x forward).
Maps: world.export_grid_map(dir) (ROS map_server PNG + YAML), world.write_landmark_map(path).
"""
import importlib

from hearing.blas import one_blas_thread

from .errors import InvalidArgument, MotionBlocked, MotionInterrupted, RobotError, UnsupportedOperation

one_blas_thread()  # before numpy is used from several threads (hearing/blas.py)

# the simulator (pybullet) loads when one of these is first used, not with the package: what a Core
# needs of any robot (robots.interface, robots.errors) imports without it
_SIMULATOR = {"RobotAPI": ".api", "OdometryNoise": ".odometry", "Robot": ".robot", "HOUSES": ".world",
              "ROBOT_SPECS": ".bodies", "GroundTruth": ".world", "World": ".world"}


def __getattr__(name: str):
    if name not in _SIMULATOR:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_SIMULATOR[name], __name__), name)
    globals()[name] = value
    return value


__all__ = ["World", "Robot", "RobotAPI", "OdometryNoise", "GroundTruth", "HOUSES", "ROBOT_SPECS", "RobotError",
           "UnsupportedOperation", "InvalidArgument", "MotionBlocked", "MotionInterrupted"]
