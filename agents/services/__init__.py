"""Platform service implementations, independent of SPADE.

    from agents.services import SERVICES, ServiceContext, ServiceState, run_service
    state = ServiceState()                         # once per Platform Agent (shared, thread-safe)
    state.preload_maps("maps/")                    # optional: shared map_server maps
    spec = SERVICES["path_planning_plan_path_2d"]
    reply = await loop.run_in_executor(pool, spec.run, request, ServiceContext(user, state))

Each ServiceSpec.run(request, ctx) is synchronous, takes the registered request model and returns
its reply model, raising agents.services.errors.ServiceError(reason, code) on bad input.
The registry (agents/services/registry.py) is imported at first use of SERVICES, ServiceSpec or
run_service: importing one service module (a RApp's `rapps.sdk.vision` needs images and
localization) must not import them all (speech, rendering: ~0.4 s of a Cloud Agent's start).
"""
from __future__ import annotations

from .context import ServiceContext, ServiceState
from .errors import ServiceError

_REGISTRY = ("SERVICES", "ServiceSpec", "run_service")


def __getattr__(name: str):
    if name in _REGISTRY:
        from . import registry
        return getattr(registry, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["SERVICES", "ServiceSpec", "ServiceContext", "ServiceState", "ServiceError", "run_service"]
