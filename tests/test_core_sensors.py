"""The Core's events from the new sensors: bumper and touch (agents/core_contacts.py) as typed notifications,
and the depth camera's nearest point in the Elektron's obstacle events (agents/core_depth.py): a low box
the laser's plane passes over."""
from types import SimpleNamespace

from agents.core_contacts import ContactEvents
from agents.core_depth import with_depth
from agents.core_events import CoreEvents
from ontology.notifications import EventTopic, SubscribeEvents
from ontology.robot import GetLaserScan, MoveTo

from .test_core_events import EventsHost, no_echo


class _Watcher:
    def __init__(self, robot):
        self.robot, self.published = robot, []

    async def publish(self, topic, ttl_s, **data):
        self.published.append((topic, ttl_s, data))


async def test_touch_and_bumper_changes_become_events_in_order():
    from robots import MotionBlocked, RobotAPI, World

    world = World.from_file("small", seed=1, render="inline")
    try:
        core = _Watcher(RobotAPI(world.add_robot("nao", pose=(2.8, 2.4, 0.0))))
        watch = ContactEvents(core)
        await world.touch("nao", "head_front", 0.3)  # before the first read: not reported (before the subscription)
        await watch.run()
        assert core.published == []
        await world.touch("nao", "hand_left", 0.3)
        try:
            await core.robot.move_to(MoveTo(x=1.0))  # into the inner wall
        except MotionBlocked:
            pass
        await watch.run()
        seen = [(t, d["sensor"], d["pressed"]) for t, _, d in core.published]
        assert seen[:2] == [(EventTopic.TOUCH, "hand_left", True), (EventTopic.TOUCH, "head_front", False)]
        assert {s[1:] for s in seen[2:]} >= {("hand_left", False), ("bumper_left", True), ("bumper_right", True)}
        assert all(ttl == 2.0 and d["kind"] in ("touch", "bumper") for _, ttl, d in core.published)
        assert [d["seq"] for _, _, d in core.published] == sorted(d["seq"] for _, _, d in core.published)
    finally:
        world.close()


async def test_subscribing_to_bumper_starts_the_contact_watch_only_on_a_robot_with_contacts():
    from robots import RobotAPI, World

    world = World.from_file("small", seed=1, render="inline")
    try:
        ctx = SimpleNamespace(sender="dyn-1@localhost")
        nao = CoreEvents(EventsHost(RobotAPI(world.add_robot("nao"))), no_echo)
        await nao._on_subscribe(SubscribeEvents(topics=["bumper", "touch"]), ctx)
        assert isinstance(nao.host.active.get("contact-events"), ContactEvents)
        nao.end_subscriptions()
        assert nao.host.active == {}
        el = CoreEvents(EventsHost(RobotAPI(world.add_robot("elektron"))), no_echo)
        await el._on_subscribe(SubscribeEvents(topics=["touch"]), ctx)
        assert el.host.active == {}
    finally:
        world.close()


async def test_the_elektrons_obstacle_reading_sees_a_low_box_the_laser_misses():
    from robots import RobotAPI, World

    toy = {"kind": "box", "id": "toy", "at": 0.0, "position": [2.0, 2.4], "size": [0.3, 0.4, 0.15]}
    world = World.from_file("small", seed=1, disturbances=[toy])  # render processes, as a run's
    try:
        el = RobotAPI(world.add_robot("elektron", pose=(1.0, 2.4, 0.0)))
        scan = await el.get_laser_scan(GetLaserScan())
        ahead = [r for i, r in enumerate(scan.ranges) if abs(scan.angle_min + i * scan.angle_increment) < 0.52]
        assert min(ahead) > 2.0  # the laser's plane (0.26 m) passes over the box (0.15 m)
        echo = await with_depth(el, None)
        assert echo is not None
        # the box's near face is 0.85 m ahead of the base's centre, 0.71 m of the bottom Kinect's mount (the
        # floor it sees from 0.3 m ahead is no obstacle)
        assert 0.6 < echo.margin_m < 0.8 and 0.75 < echo.range_m < 0.95 and abs(echo.bearing_rad) < 0.3
        far = SimpleNamespace(margin_m=0.3, range_m=0.5, bearing_rad=0.0)
        assert await with_depth(el, far) is far  # a nearer range reading stands
    finally:
        world.close()
