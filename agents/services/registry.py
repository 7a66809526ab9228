"""The registry of Platform services: action name -> implementation (see agents/services/__init__.py)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import ontology.services as _models  # noqa: F401  (registers the actions)
from ontology.registry import Action, Content, lookup
from ontology.errors import ErrorCode

from . import (cognitive, email, faces, geolocation, hazard, home, information, interpretation, knowledge, localization,
               navigation, obstacles, scenes, speech, vision)
from .context import ServiceContext
from .errors import ServiceError


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    request: type[Action]
    reply: type[Content]
    run: Callable[[Action, ServiceContext], Content]


_IMPLS: dict[str, Callable] = {
    "path_planning_upload_map": navigation.upload_map,
    "path_planning_list_maps": navigation.list_maps,
    "path_planning_plan_path_2d": navigation.plan_path_2d,
    "path_planning_add_obstacle": obstacles.add_obstacle,
    "path_planning_clear_obstacles": obstacles.clear_obstacles,
    "path_planning_list_obstacles": obstacles.list_obstacles,
    "qr_detection": localization.qr_detection,
    "compute_global_pose": localization.compute_global_pose,
    "hazard_detection_door_check": hazard.door_check,
    "hazard_detection_light_check": hazard.light_check,
    "home_upload_info": home.upload_info,
    "home_get_info": home.get_info,
    "face_detection": vision.face_detection,
    "human_detection": vision.human_detection,
    "object_detection_learn_object": vision.learn_object,
    "object_detection_find_objects": vision.find_objects,
    "object_detection_clear_models": vision.clear_objects,
    "face_recognition_learn": faces.learn_face,
    "face_recognition_recognize": faces.recognize_faces,
    "face_recognition_list": faces.list_faces,
    "face_recognition_forget": faces.forget_face,
    "scene_recognition_learn": scenes.learn_scene,
    "scene_recognition_recognize": scenes.recognize_scene,
    "scene_recognition_forget": scenes.forget_scenes,
    "geolocation": geolocation.geolocate,
    "interpret_command": interpretation.interpret_command,
    "weather_report_current": information.weather_current,
    "weather_report_forecast": information.weather_forecast,
    "news_explore": information.news_explore,
    "email_send": email.email_send,
    "email_fetch": email.email_fetch,
    "ontology_subclasses_of": knowledge.subclasses_of,
    "ontology_superclasses_of": knowledge.superclasses_of,
    "ontology_is_subclass_of": knowledge.is_subclass_of,
    "cognitive_test_chooser": cognitive.choose_test,
    "cognitive_record_performance": cognitive.record_performance,
    "cognitive_get_history": cognitive.get_history,
    "speech_recognition": speech.speech_recognition,
    "speech_noise_profile": speech.noise_profile,
    "text_to_speech": speech.text_to_speech,
}


def _spec(name: str, fn: Callable) -> ServiceSpec:
    req = lookup("platform", name)
    return ServiceSpec(name, req, req.reply_model, fn)  # type: ignore[arg-type]


SERVICES: dict[str, ServiceSpec] = {n: _spec(n, fn) for n, fn in _IMPLS.items()}


def run_service(name: str, request: Action, ctx: ServiceContext) -> Content:
    """Run a service by action name after checking the request type (ServiceError otherwise)."""
    spec = SERVICES.get(name)
    if spec is None:
        raise ServiceError(f"unknown service {name!r}", ErrorCode.UNKNOWN_SERVICE)
    if not isinstance(request, spec.request):
        raise ServiceError(f"service {name!r} expects {spec.request.__name__}", ErrorCode.BAD_REQUEST)
    return spec.run(request, ctx)

