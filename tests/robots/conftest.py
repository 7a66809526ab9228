import math

import pytest

from robots import RobotAPI, World


@pytest.fixture
def make_world():
    worlds = []

    def make(name="small", seed=1, overrides=None, **kw):
        w = World.from_file(name, seed=seed, overrides=overrides, **kw)
        worlds.append(w)
        return w

    yield make
    for w in worlds:
        w.close()


@pytest.fixture
def small(make_world):
    return make_world("small", seed=1, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}})


def api_at(world, kind, pose, **kw):
    return RobotAPI(world.add_robot(kind, pose=(pose[0], pose[1], math.radians(pose[2])), **kw))
