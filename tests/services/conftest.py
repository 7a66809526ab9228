import pytest

from agents.services.context import ServiceContext, ServiceState


@pytest.fixture
def state(tmp_path):
    return ServiceState(work_dir=tmp_path)


@pytest.fixture
def ctx(state):
    return ServiceContext(user="alice", state=state)
