"""Every error a robot action or a Platform service answers, and when: one table per kind of fact.

A RApp sees each as an exception of rapps.sdk with its code (`e.code == ErrorCode.UNKNOWN_HOME`):
`RequestRefused` (refuse: nothing was done), `RequestFailed` (failure: it was tried), `NotUnderstood`
(the content does not fit the model), `RequestTimeout` (no answer in time; a read is sent again first).

- SERVICE_COMMON / ROBOT_COMMON: what any service / any robot action may answer (token, grant,
  content, load); ROBOT_DEVICE, ROBOT_MOTION, ROBOT_BASE, ROBOT_RELATIVE add to the actions that hold
  a device, move, move the base, or move relative to where the robot is (ontology/robot_actions.py
  says which);
- SERVICE_ERRORS / ROBOT_ERRORS: what each one answers beyond those.

docs/services.md and docs/robot-api.md show them (rapps/sdk/reference.py); tests/test_reference.py
checks SERVICE_ERRORS against the codes agents/services/ raises and ROBOT_ERRORS against robots/api.py.
"""
from __future__ import annotations

from typing import Literal, NamedTuple

from .errors import ErrorCode as E
from .robot_actions import RELATIVE_MOTIONS, facts

Answer = Literal["refuse", "failure", "not-understood", "timeout"]
EXCEPTION = {"refuse": "RequestRefused", "failure": "RequestFailed", "not-understood": "NotUnderstood",
             "timeout": "RequestTimeout"}


# {code: when} answered as failure, or {code: (answer, when)}
Errors = dict[str, str | tuple[Answer, str]]


class ErrorFact(NamedTuple):
    code: str
    answer: Answer
    when: str


F = ErrorFact
_CONTENT = F(E.NOT_UNDERSTOOD, "not-understood", "the content does not fit the request model (a field's type "
             "or range, an unknown field); the reason names each field")
_TIMEOUT = F(E.TIMEOUT, "timeout", "no answer within the call's `_timeout` (raised by the SDK, not sent)")

SERVICE_COMMON: tuple[ErrorFact, ...] = (
    F(E.NO_TOKEN, "refuse", "the request carries no token (the SDK adds the run's)"),
    F(E.BAD_TOKEN, "refuse", "the token is unknown or was issued to another agent"),
    F(E.EXPIRED_TOKEN, "refuse", "the token has expired"),
    F(E.PERMISSION, "refuse", "the RApp's manifest does not declare the service (`services`)"),
    F(E.BUSY, "refuse", "the Platform has too many calls in progress: retry shortly"),
    _CONTENT,
    F(E.SERVICE_ERROR, "failure", "the service failed unexpectedly (its reason says how)"),
    _TIMEOUT,
)

ROBOT_COMMON: tuple[ErrorFact, ...] = (
    F(E.NOT_SUPERVISOR, "refuse", "the sender is not the robot's current supervisor (its run has ended)"),
    F(E.PERMISSION, "refuse", "the RApp's manifest does not declare the action's robot-API group (`robot_api`)"),
    _CONTENT,
    F(E.ROBOT_ERROR, "failure", "the robot failed unexpectedly (its reason says how)"),
    F(E.WORLD_CLOSED, "failure", "the simulated world closed while the call was pending"),
    _TIMEOUT,
)
ROBOT_DEVICE = (F(E.LOCKED, "refuse", "another agent holds the device's lock (lock_resource) for over 60 s"),)
ROBOT_MOTION = (F(E.INTERRUPTED, "failure", "a newer motion of the same effector, move_stop or rest pre-empted it"),)
ROBOT_BASE = (F(E.BLOCKED, "failure", "an obstacle stopped the base (the safety stop held it and it could not go on)"),)
ROBOT_RELATIVE = (F(E.ESTOP, "failure", "the emergency stop cut it: a relative motion is not issued again "
                    "after the resume (issue it again from where the robot stands)"),)

_IMAGE: Errors = {E.BAD_IMAGE: "`image_b64` is not base64 or not a PNG/JPEG image"}
_CLASS: Errors = {E.UNKNOWN_CLASS: "the class is not in the household ontology"}
_MAP: Errors = {E.NOT_FOUND: "no map `map_id` for this user (path_planning_upload_map)"}

# service -> {code: when} answered as failure, or {code: (answer, when)}
SERVICE_ERRORS: dict[str, Errors] = {
    "ping": {},
    "issue_app_token": {E.UNKNOWN_SERVICE: ("refuse", "the RApp declares a service the Platform does not know")},
    "start_cloud_agent": {
        E.FORBIDDEN: ("refuse", "not a Dynamic Agent's token, another agent named as owner, or the run has "
                                "started its Cloud Agent already (one per run)"),
        E.NO_CLOUD_PART: ("refuse", "the RApp has no Cloud Agent part"),
        E.STORE: "the package could not be fetched from the Store",
        E.CLOUD_START: "the Cloud Agent did not start (the reason holds the end of its stderr)"},
    "stop_cloud_agent": {E.NOT_FOUND: ("refuse", "no Cloud Agent of that JID"),
                         E.FORBIDDEN: ("refuse", "the sender does not own it")},
    "release_cloud_agents": {E.FORBIDDEN: ("refuse", "the Cloud Agents are not the sender's to stop")},
    "path_planning_upload_map": {E.BAD_MAP: "the YAML or image is not a map_server map (the reason says what)",
                                 E.BAD_IMAGE: "`png_b64` is not base64"},
    "path_planning_list_maps": {},
    "path_planning_plan_path_2d": {E.NOT_FOUND: "the map was removed while the plan was computed (a plan that "
                                                "cannot be made is an answer: `plan_found`, `reason`)",
                                   E.UNAVAILABLE: "the Platform's planning workers are stopping"},
    "path_planning_add_obstacle": {**_MAP, E.INVALID_ARGUMENT: "the mark's size is not positive and finite",
                                   E.OUT_OF_RANGE: "the mark's centre is outside the map",
                                   E.TOO_LARGE: "the user has as many marks as allowed: clear some first"},
    "path_planning_clear_obstacles": {**_MAP, E.INVALID_ARGUMENT: "a mark id or the region is malformed"},
    "path_planning_list_obstacles": _MAP,
    "qr_detection": {**_IMAGE, E.POSE_FAILED: "a code was found but its pose could not be estimated"},
    "compute_global_pose": {E.BAD_TRANSFORM: "a matrix is not a finite 4x4 transform",
                            E.UNKNOWN_MARKER: "none of the observed codes is in the landmark map"},
    "hazard_detection_door_check": {**_IMAGE, E.BAD_REQUEST: 'method "geometry" without the `geometry` field',
                                    E.BAD_TRANSFORM: "`geometry.camera_to_world` is not a 4x4 matrix"},
    "hazard_detection_light_check": _IMAGE,
    "home_upload_info": {},
    "home_get_info": {E.UNKNOWN_HOME: "no home `home_id` was uploaded for this user (home_upload_info)"},
    "face_detection": {**_IMAGE, E.UNAVAILABLE: "this OpenCV build has no Haar cascades"},
    "human_detection": {**_IMAGE, E.UNAVAILABLE: "this OpenCV build has no HOG detector"},
    "object_detection_learn_object": {**_IMAGE, E.NO_FEATURES: "the image has too little texture to learn"},
    "object_detection_find_objects": {**_IMAGE, E.NO_MODELS: "no object learned yet for this user"},
    "object_detection_clear_models": {},
    "face_recognition_learn": {**_IMAGE, E.NO_FEATURES: "no single face found in the image",
                               E.UNAVAILABLE: "the face models are not available"},
    "face_recognition_recognize": {**_IMAGE, E.NO_MODELS: "no face learned yet for this user",
                                   E.UNAVAILABLE: "the face models are not available"},
    "face_recognition_list": {},
    "face_recognition_forget": {E.NOT_FOUND: "no person of that name learned for this user"},
    "scene_recognition_learn": _IMAGE,
    "scene_recognition_recognize": {**_IMAGE, E.NO_MODELS: "no scene learned yet for this user"},
    "scene_recognition_forget": {},
    "geolocation": {E.INVALID_ARGUMENT: "`ip` is not an IP address",
                    E.NOT_FOUND: "the address is not in the offline geolocation table"},
    "interpret_command": {E.NO_RAPP: "no RApp is available for the robot type",
                          E.NOT_UNDERSTOOD: "the text matches no RApp",
                          E.AMBIGUOUS: "the text matches two RApps equally well",
                          E.INVALID: "a schedule's time is missing or not a time of day"},
    "weather_report_current": {E.UNKNOWN_CITY: "no weather data for the city (the reason lists the known ones)"},
    "weather_report_forecast": {E.UNKNOWN_CITY: "no weather data for the city (the reason lists the known ones)"},
    "news_explore": {},
    "email_send": {E.BAD_RECIPIENT: "a recipient is not an e-mail address"},
    "email_fetch": {},
    "ontology_subclasses_of": _CLASS,
    "ontology_superclasses_of": _CLASS,
    "ontology_is_subclass_of": _CLASS,
    "cognitive_test_chooser": {E.UNKNOWN_TEST_TYPE: "the test type is not one of the known ones"},
    "cognitive_record_performance": {E.UNKNOWN_TEST: "no test with that id"},
    "cognitive_get_history": {},
    "speech_recognition": {E.MALFORMED: "`audio_b64` is not base64",
                           E.INVALID: "the recording is too short, silent or clipped, or the sentences do not parse",
                           E.UNSUPPORTED: "the language is not available, or no sentence can be pronounced",
                           E.NOT_FOUND: "no noise profile of that name (speech_noise_profile)"},
    "speech_noise_profile": {E.MALFORMED: "`audio_b64` is not base64",
                             E.INVALID: "the recording is too short or clipped"},
    "text_to_speech": {},
}

_AUDIO: Errors = {E.MALFORMED: "`data_b64` is not base64 or not a 16-bit mono WAV"}
_CAMERA: Errors = {E.INVALID_ARGUMENT: "unknown camera or resolution"}
# robot action -> {code: when} answered as failure, or {code: (answer, when)}
ROBOT_ERRORS: dict[str, Errors] = {
    "say": {E.UNSUPPORTED: "the robot has no speech synthesis (an Elektron: report the text instead)"},
    "word_spotting": {E.INVALID_ARGUMENT: "no word given"},
    "capture_audio": {E.INVALID_ARGUMENT: "`since` is later than the simulation time"},
    "play_audio": _AUDIO,
    "microphone_energy": {},
    "capture_image": _CAMERA,
    "set_camera_param": {E.INVALID_ARGUMENT: "unknown camera or parameter, or a gain/exposure not > 0"},
    "set_camera_params": {E.INVALID_ARGUMENT: "unknown camera, or a gain/exposure not > 0"},
    "get_camera_info": _CAMERA,
    "move_to": {},
    "move_vel": {E.UNSUPPORTED: "a sideways `y` on a differential drive (an Elektron)"},
    "move_stop": {},
    "move_along_path": {E.INVALID_ARGUMENT: "no pose given"},
    "look_at_point": {},
    "get_global_pose": {},
    "set_global_pose": {},
    "get_transform": {E.INVALID_ARGUMENT: "unknown chain, or `space` not robot/global"},
    "move_joint": {E.INVALID_ARGUMENT: "unknown joint, joints and angles of different lengths, or a speed not in (0, 1]"},
    "get_joint_angles": {E.INVALID_ARGUMENT: "unknown joint"},
    "take_predefined_posture": {E.INVALID_ARGUMENT: "unknown posture for this robot, or a speed not in (0, 1]"},
    "rest": {},
    "get_sonars": {E.UNSUPPORTED: "the robot has no sonars (an Elektron: get_laser_scan)"},
    "get_laser_scan": {E.UNSUPPORTED: "the robot has no laser scanner (a NAO: get_sonars)"},
    "get_contacts": {E.UNSUPPORTED: "the robot has no contact sensors (an Elektron)"},
    "capture_depth": {E.UNSUPPORTED: "the robot has no depth camera (a NAO)",
                      E.INVALID_ARGUMENT: "unknown depth camera, or a resolution above the Kinect's 320x240"},
    "get_pose_estimate": {},
    "add_pose_fix": {},
    "lock_resource": {E.UNKNOWN_RESOURCE: ("refuse", "not a device (base, head, joints, camera, speaker, microphone)")},
    "free_resource": {E.NOT_HOLDER: "the sender does not hold the lock"},
}
del F


def _fact(code: str, spec: str | tuple[Answer, str]) -> ErrorFact:
    return ErrorFact(code, "failure", spec) if isinstance(spec, str) else ErrorFact(code, *spec)


def service_errors(name: str) -> list[ErrorFact]:
    """Every error the Platform service `name` may answer: its own, then the common ones."""
    return [_fact(c, s) for c, s in SERVICE_ERRORS[name].items()] + list(SERVICE_COMMON)


def robot_errors(name: str) -> list[ErrorFact]:
    """Every error the robot action `name` may answer: its own, then what its facts add, then the common ones."""
    row = facts(name)
    own = [_fact(c, s) for c, s in ROBOT_ERRORS[name].items()]
    if row.group == "resources":
        return own + [f for f in ROBOT_COMMON if f.code != E.PERMISSION]
    out = own + (list(ROBOT_DEVICE) if row.device else [])
    out += list(ROBOT_MOTION) if row.motion else []
    out += list(ROBOT_BASE) if row.motion and row.device == "base" else []
    out += list(ROBOT_RELATIVE) if name in RELATIVE_MOTIONS else []
    return out + list(ROBOT_COMMON)
