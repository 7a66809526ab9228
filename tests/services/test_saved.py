"""The Platform's services keep every per-user datum in their data directory (agents/services/saved.py):
a fresh state on the same folder answers as the old one did. The restart of a real `rapp agent
platform` process is in tests/test_platform_restart.py."""
from __future__ import annotations

import base64
import os
from pathlib import Path

import numpy as np
import pytest

from agents.schema import SchemaError
from agents.services import run_service
from agents.services.context import ServiceContext, ServiceState
from agents.services.maps import encode_map
from agents.services.saved import SavedData
from ontology.services.home import GetHomeInfo, HomeInfo, RoomSpec, UploadHomeInfo
from ontology.services.knowledge import ChooseCognitiveTest, GetHistory, RecordPerformance
from ontology.services.navigation import AddObstacle, ClearObstacles, ListMaps, ListObstacles, UploadMap
from ontology.services.speech import SpeechNoiseProfile
from ontology.services.vision import ClearObjects, FindObjects, LearnObject

DATA = Path(__file__).resolve().parent.parent / "data"


def photo(name: str) -> str:
    return base64.b64encode((DATA / name).read_bytes()).decode("ascii")


def call(state, user, name, req):
    return run_service(name, req, ServiceContext(user=user, state=state))


def _map_request(map_id="flat"):
    blocked = np.zeros((40, 60), bool)
    blocked[0, :] = blocked[-1, :] = blocked[:, 0] = blocked[:, -1] = True
    blocked[10:30, 25] = True
    png, text = encode_map(blocked, 0.1, (-1.0, -2.0, 0.0))
    return UploadMap(map_id=map_id, png_b64=base64.b64encode(png).decode(), yaml_text=text), blocked


def _wav_noise() -> str:
    import io
    import wave

    pcm = (np.random.default_rng(3).normal(0, 800, 16000)).astype(np.int16)
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1), w.setsampwidth(2), w.setframerate(16000), w.writeframes(pcm.tobytes())
    return base64.b64encode(buf.getvalue()).decode()


def test_every_per_user_datum_survives_a_new_state_on_the_same_folder(tmp_path):
    state = ServiceState.keeping(tmp_path)
    req, blocked = _map_request()
    call(state, "alice", "path_planning_upload_map", req)
    home = HomeInfo(home_id="home", map_id="flat", rooms=[RoomSpec(name="kitchen", rect=[0, 0, 2, 2])])
    call(state, "alice", "home_upload_info", UploadHomeInfo(info=home))
    call(state, "alice", "object_detection_learn_object", LearnObject(name="coffee", image_b64=photo("coffee.jpg")))
    call(state, "bob", "object_detection_learn_object", LearnObject(name="astronaut", image_b64=photo("astronaut.jpg")))
    call(state, "bob", "object_detection_clear_models", ClearObjects())  # a clear is kept too
    tests = call(state, "alice", "cognitive_test_chooser", ChooseCognitiveTest(test_type="arithmetic"))
    first = call(state, "alice", "cognitive_record_performance", RecordPerformance(test_id=tests.test_id, score=80))
    call(state, "alice", "cognitive_record_performance", RecordPerformance(test_id=tests.test_id, score=35))
    layer = call(state, "alice", "path_planning_add_obstacle", AddObstacle(map_id="flat", x=2.0, y=0.5, radius_m=0.3,
                                                                          ttl_s=600, note="box"))
    call(state, "alice", "path_planning_add_obstacle", AddObstacle(map_id="flat", x=3.0, y=0.5, radius_m=0.2))
    call(state, "alice", "path_planning_clear_obstacles", ClearObstacles(map_id="flat", x=3.0, y=0.5, radius_m=0.1))
    call(state, "alice", "speech_noise_profile", SpeechNoiseProfile(audio_b64=_wav_noise(), name="kitchen"))
    state.close()

    again = ServiceState.keeping(tmp_path)
    maps = call(again, "alice", "path_planning_list_maps", ListMaps()).maps
    assert [(m.map_id, m.width, m.height, m.resolution, m.origin[:2]) for m in maps] == \
        [("flat", 60, 40, 0.1, [-1.0, -2.0])]
    assert np.array_equal(again.maps.get("alice", "flat").blocked, blocked)
    assert again.maps.get("bob", "flat") is None  # nobody else's
    assert call(again, "alice", "home_get_info", GetHomeInfo(home_id="home")) == home
    found = call(again, "alice", "object_detection_find_objects", FindObjects(image_b64=photo("coffee.jpg"))).objects
    assert [f.name for f in found] == ["coffee"]
    with pytest.raises(Exception, match="no objects learned"):
        call(again, "bob", "object_detection_find_objects", FindObjects(image_b64=photo("coffee.jpg")))
    history = call(again, "alice", "cognitive_get_history", GetHistory()).records
    assert [r.score for r in history] == [80, 35] and history[0] == first
    marks = call(again, "alice", "path_planning_list_obstacles", ListObstacles(map_id="flat")).obstacles
    assert [(k.id, k.x, k.note) for k in marks] == [(layer.added, 2.0, "box")]
    assert 590 < marks[0].expires_in_s <= 600
    new = call(again, "alice", "path_planning_add_obstacle", AddObstacle(map_id="flat", x=4.0, y=0.5, radius_m=0.2))
    assert new.added == "obs-3"  # ids go on where they were, never reused
    assert ("alice", "kitchen") in again.store("speech_noise_profiles", dict)
    again.close()


def test_files_are_private_and_a_damaged_blob_loses_that_record_only(tmp_path):
    state = ServiceState.keeping(tmp_path / "platform")
    call(state, "alice", "object_detection_learn_object", LearnObject(name="coffee", image_b64=photo("coffee.jpg")))
    call(state, "alice", "object_detection_learn_object", LearnObject(name="man", image_b64=photo("cameraman.jpg")))
    state.close()
    folder = tmp_path / "platform"
    assert os.stat(folder).st_mode & 0o777 == 0o700
    assert os.stat(folder / "services.db").st_mode & 0o777 == 0o600
    blobs = sorted(folder.glob("blobs/*/*"))
    assert len(blobs) == 2 and all(b.stat().st_mode & 0o777 == 0o600 for b in blobs)
    blobs[0].write_bytes(b"garbage")
    again = ServiceState.keeping(folder)
    from agents.services.vision import models
    assert len(models(ServiceContext(user="alice", state=again)).models["alice"]) == 1
    again.close()


def test_an_unreferenced_blob_is_swept_and_a_replaced_one_deleted(tmp_path):
    saved = SavedData(tmp_path)
    saved.put("map", "alice", "m", {"a": 1}, b"one")
    saved.put("map", "alice", "m", {"a": 2}, b"two")  # replaced: the old blob goes
    assert len(list(tmp_path.glob("blobs/*/*"))) == 1
    stray = tmp_path / "blobs" / "ab" / ("ab" + "0" * 62)
    stray.parent.mkdir(exist_ok=True)
    stray.write_bytes(b"left by a crash")
    saved.close()
    saved = SavedData(tmp_path)
    assert not stray.exists()
    assert [(r.meta, r.blob) for r in saved.records("map")] == [({"a": 2}, b"two")]
    assert saved.delete("map", "alice") == 1 and not list(tmp_path.glob("blobs/*/*"))
    saved.close()


def test_a_newer_schema_is_refused_untouched(tmp_path):
    import sqlite3

    SavedData(tmp_path).close()
    db = sqlite3.connect(tmp_path / "services.db")
    db.execute("PRAGMA user_version = 99")
    db.commit()
    db.close()
    with pytest.raises(SchemaError, match="schema version 99, newer than this program's 1"):
        SavedData(tmp_path)
