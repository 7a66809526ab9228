"""Platform service implementations, independent of SPADE.

    from agents.services import SERVICES, ServiceContext, ServiceState, run_service
    state = ServiceState()                         # once per Platform Agent (shared, thread-safe)
    state.preload_maps("maps/")                    # optional: shared map_server maps
    spec = SERVICES["path_planning_plan_path_2d"]
    reply = await loop.run_in_executor(pool, spec.run, request, ServiceContext(user, state))

Each ServiceSpec.run(request, ctx) is synchronous, takes the registered request model and returns
its reply model, raising agents.services.errors.ServiceError(reason, code) on bad input.
`cpu_heavy` marks services better run in a process / dedicated thread pool.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import ontology.services as _models  # noqa: F401  (registers the actions)
from ontology.registry import Action, Content, lookup

from . import cognitive, email, hazard, home, information, interpretation, knowledge, localization, navigation, vision
from .context import ServiceContext, ServiceState
from .errors import ServiceError


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    request: type[Action]
    reply: type[Content]
    run: Callable[[Action, ServiceContext], Content]
    cpu_heavy: bool = False


_IMPLS: dict[str, tuple[Callable, bool]] = {
    "path_planning_upload_map": (navigation.upload_map, False),
    "path_planning_list_maps": (navigation.list_maps, False),
    "path_planning_plan_path_2d": (navigation.plan_path_2d, True),
    "qr_detection": (localization.qr_detection, True),
    "compute_global_pose": (localization.compute_global_pose, False),
    "hazard_detection_door_check": (hazard.door_check, True),
    "hazard_detection_light_check": (hazard.light_check, False),
    "home_upload_info": (home.upload_info, False),
    "home_get_info": (home.get_info, False),
    "face_detection": (vision.face_detection, True),
    "human_detection": (vision.human_detection, True),
    "object_detection_learn_object": (vision.learn_object, True),
    "object_detection_find_objects": (vision.find_objects, True),
    "object_detection_clear_models": (vision.clear_objects, False),
    "interpret_command": (interpretation.interpret_command, False),
    "weather_report_current": (information.weather_current, False),
    "weather_report_forecast": (information.weather_forecast, False),
    "news_explore": (information.news_explore, False),
    "email_send": (email.email_send, False),
    "email_fetch": (email.email_fetch, False),
    "ontology_subclasses_of": (knowledge.subclasses_of, False),
    "ontology_superclasses_of": (knowledge.superclasses_of, False),
    "ontology_is_subclass_of": (knowledge.is_subclass_of, False),
    "cognitive_test_chooser": (cognitive.choose_test, False),
    "cognitive_record_performance": (cognitive.record_performance, False),
    "cognitive_get_history": (cognitive.get_history, False),
}


def _spec(name: str, fn: Callable, heavy: bool) -> ServiceSpec:
    req = lookup("platform", name)
    return ServiceSpec(name, req, req.reply_model, fn, heavy)  # type: ignore[arg-type]


SERVICES: dict[str, ServiceSpec] = {n: _spec(n, fn, heavy) for n, (fn, heavy) in _IMPLS.items()}


def run_service(name: str, request: Action, ctx: ServiceContext) -> Content:
    """Run a service by action name after checking the request type (ServiceError otherwise)."""
    spec = SERVICES.get(name)
    if spec is None:
        raise ServiceError(f"unknown service {name!r}", "unknown_service")
    if not isinstance(request, spec.request):
        raise ServiceError(f"service {name!r} expects {spec.request.__name__}", "bad_request")
    return spec.run(request, ctx)


__all__ = ["SERVICES", "ServiceSpec", "ServiceContext", "ServiceState", "ServiceError", "run_service"]
