"""The table of Platform services: per action name, its implementation, whether it runs in the
service pool's worker processes, and what of the Platform's state a pooled call reads and writes
(see agents/services/__init__.py, pool.py and state_parts.py). The request and reply models come from
the action registered under the same name in ontology/services/; tests/services/test_service_table.py
checks the table against them and against the pool."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import ontology.services as _models  # noqa: F401  (registers the actions)
from ontology.registry import Action, Content, lookup
from ontology.errors import ErrorCode

from . import (cognitive, email, faces, geolocation, hazard, home, information, interpretation, knowledge, localization,
               navigation, obstacles, scenes, speech, vision)
from . import state_parts as parts
from .context import ServiceContext
from .errors import ServiceError


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    request: type[Action]
    reply: type[Content]
    run: Callable[[Action, ServiceContext], Content]
    # CPU-bound: runs in the Platform's worker processes when it has some (agents/services/pool.py)
    pooled: bool = False
    # what of the Platform's state a pooled call takes along: a reader per store (state_parts.py)
    reads: Mapping[str, Callable[[Action, ServiceContext], Any]] = field(default_factory=dict)
    # the stores a pooled call gives back, merged into the Platform's state (state_parts.merge)
    writes: tuple[str, ...] = ()
    # plans on the caller's grid map (request.map_id, its obstacle marks): workers keep maps by content
    on_map: Callable[..., Content] | None = None


class Row(NamedTuple):
    run: Callable
    pooled: bool = False
    reads: dict[str, Callable] = {}
    writes: tuple[str, ...] = ()
    on_map: Callable | None = None


POOL = True  # the "pooled" column: CPU-bound (vision, hazard checks, speech, planning)
# One row per Platform service: its implementation, whether it is pooled, and for a pooled one the
# state it reads and writes. Every other service runs in a thread of the Platform with its whole state.
R = Row
SERVICE_TABLE: dict[str, Row] = {
    "path_planning_upload_map":       R(navigation.upload_map),
    "path_planning_list_maps":        R(navigation.list_maps),
    "path_planning_plan_path_2d":     R(navigation.plan_path_2d, POOL, on_map=navigation.plan_on_map),
    "path_planning_add_obstacle":     R(obstacles.add_obstacle),
    "path_planning_clear_obstacles":  R(obstacles.clear_obstacles),
    "path_planning_list_obstacles":   R(obstacles.list_obstacles),
    "qr_detection":                   R(localization.qr_detection, POOL),
    "compute_global_pose":            R(localization.compute_global_pose),
    "hazard_detection_door_check":    R(hazard.door_check, POOL),
    "hazard_detection_light_check":   R(hazard.light_check, POOL),
    "home_upload_info":               R(home.upload_info),
    "home_get_info":                  R(home.get_info),
    "face_detection":                 R(vision.face_detection, POOL),
    "human_detection":                R(vision.human_detection, POOL),
    "object_detection_learn_object":  R(vision.learn_object),
    "object_detection_find_objects":  R(vision.find_objects, POOL, {"objects": parts.callers_objects}),
    "object_detection_clear_models":  R(vision.clear_objects),
    "face_recognition_learn":         R(faces.learn_face, POOL, {"faces": parts.named_persons_faces}, ("faces",)),
    "face_recognition_recognize":     R(faces.recognize_faces, POOL, {"faces": parts.callers_faces}),
    "face_recognition_list":          R(faces.list_faces),
    "face_recognition_forget":        R(faces.forget_face),
    "scene_recognition_learn":        R(scenes.learn_scene),
    "scene_recognition_recognize":    R(scenes.recognize_scene),
    "scene_recognition_forget":       R(scenes.forget_scenes),
    "geolocation":                    R(geolocation.geolocate),
    "interpret_command":              R(interpretation.interpret_command),
    "weather_report_current":         R(information.weather_current),
    "weather_report_forecast":        R(information.weather_forecast),
    "news_explore":                   R(information.news_explore),
    "email_send":                     R(email.email_send),
    "email_fetch":                    R(email.email_fetch),
    "ontology_subclasses_of":         R(knowledge.subclasses_of),
    "ontology_superclasses_of":       R(knowledge.superclasses_of),
    "ontology_is_subclass_of":        R(knowledge.is_subclass_of),
    "cognitive_test_chooser":         R(cognitive.choose_test),
    "cognitive_record_performance":   R(cognitive.record_performance),
    "cognitive_get_history":          R(cognitive.get_history),
    "speech_recognition":             R(speech.speech_recognition, POOL,
                                        {"speech_noise_profiles": parts.named_noise_profile, "homes": parts.rooms_if_asked}),
    "speech_noise_profile":           R(speech.noise_profile, POOL, {"speech_noise_profiles": parts.empty},
                                        ("speech_noise_profiles",)),
    "text_to_speech":                 R(speech.text_to_speech, POOL),
}
del R


def _spec(name: str, row: Row) -> ServiceSpec:
    req = lookup("platform", name)  # the name is the action's, registered in ontology/services/
    return ServiceSpec(name, req, req.reply_model, row.run, row.pooled, row.reads, row.writes,  # type: ignore[arg-type]
                       row.on_map)


SERVICES: dict[str, ServiceSpec] = {n: _spec(n, row) for n, row in SERVICE_TABLE.items()}


def run_service(name: str, request: Action, ctx: ServiceContext) -> Content:
    """Run a service by action name after checking the request type (ServiceError otherwise)."""
    spec = SERVICES.get(name)
    if spec is None:
        raise ServiceError(f"unknown service {name!r}", ErrorCode.UNKNOWN_SERVICE)
    if not isinstance(request, spec.request):
        raise ServiceError(f"service {name!r} expects {spec.request.__name__}", ErrorCode.BAD_REQUEST)
    return spec.run(request, ctx)

