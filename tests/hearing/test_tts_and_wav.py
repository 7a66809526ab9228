"""Text to speech (eSpeak NG) and WAV in and out: the same text, voice and rate give the same samples
whatever came before and in whatever process; garbage audio is refused with its code."""
import numpy as np
import pytest

from hearing import tts
from hearing.errors import BadAudio
from hearing.wav import decode_wav, encode_wav
from ontology.errors import ErrorCode


def test_wav_round_trip_and_garbage():
    pcm = (np.sin(np.arange(1600) / 5) * 1000).astype(np.int16)
    back, rate = decode_wav(encode_wav(pcm))
    assert rate == 16000 and np.array_equal(back, pcm)
    for data, code in ((b"RIFF....WAVEjunk", ErrorCode.MALFORMED), (b"hello", ErrorCode.MALFORMED),
                       (encode_wav(pcm, 44100), ErrorCode.UNSUPPORTED),
                       (encode_wav(np.zeros(16000 * 61, np.int16)), ErrorCode.TOO_LARGE)):
        with pytest.raises(BadAudio) as e:
            decode_wav(data)
        assert e.value.code == code


def test_many_threads_speaking_first_at_once_get_the_same_speech():
    """20 NAOs in one process (bench/fleet.py) spoke their first words at once: each thread ran
    espeak_Initialize and glibc aborted on a corrupted heap. In a fresh process, six threads at once:
    none crashes, and each gets the very same samples (each synthesis loads the engine afresh)."""
    import subprocess
    import sys
    from pathlib import Path

    code = """
import threading
from hearing import tts
out = {}
threads = [threading.Thread(target=lambda i=i: out.setdefault(i, tts.synthesize("hello").tobytes())) for i in range(6)]
[t.start() for t in threads]
[t.join() for t in threads]
assert len(out) == 6 and len(set(out.values())) == 1 and len(out[0]) > 0, {k: len(v) for k, v in out.items()}
print("ok")
"""
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


def test_speech_does_not_depend_on_what_was_synthesised_before_nor_on_the_process():
    """Issue #19, deterministic per seed: eSpeak NG's wave generator kept state across calls (a text
    came out with other samples, up to half full scale apart, after other syntheses), and the breath
    noise of the "+f2" voices was seeded from the clock (other samples in every process)."""
    import hashlib
    import subprocess
    import sys
    from pathlib import Path

    said = [("check the hazards", "en-us+m3", 160), ("are the doors closed", "en+f2", 130)]
    first = [tts.synthesize(*s) for s in said]
    tts.synthesize("tell me the forecast please", "en-us+f3", 200)
    tts.synthesize("good morning", "en-us+klatt", 120)
    assert all(np.array_equal(tts.synthesize(*s), f) for s, f in zip(said, first))
    code = f"from hearing import tts; import hashlib; print(hashlib.sha1(tts.synthesize(*{said[1]!r}).tobytes()).hexdigest())"
    done = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[2], capture_output=True,
                          text=True, timeout=60)
    assert done.stdout.strip() == hashlib.sha1(first[1].tobytes()).hexdigest(), done.stderr[-1500:]
