"""The speech benchmark, tiny: one spoken keyword and one spoken sentence in a quiet room reach the
right RApps through the Core, and the result rows carry accuracy and latency."""
from bench import speech


def test_commands_cycle_conditions():
    rows = speech.commands("platform", 10, seed=0)
    assert len(rows) == 10 and len({r[2] for r in rows}) == len(speech.VOICES)
    assert {r[4] for r in rows} == set(speech.DISTANCES)
    assert all(r[0] in speech.VOCABULARY[r[1]][1] for r in rows)


async def test_speech_bench_tiny():
    metrics = {m["name"]: m for m in await speech.run(False, per_condition=1, noises=["quiet"])}
    assert metrics["speech_keyword_accuracy_quiet"]["n"] == 1
    assert metrics["speech_platform_accuracy_quiet"]["value"] == 100.0
    assert 0 < metrics["speech_platform_decided"]["value"] < 5000
