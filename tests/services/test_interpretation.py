import pytest

from agents.services.errors import ServiceError
from agents.services.interpretation import interpret_command
from ontology.services.interpretation import InterpretCommand, RAppDescription

RAPPS = [
    RAppDescription(name="hazard_detection", keywords=["lights", "door", "hazard", "closed"],
                    phrases=["check the house", "left the lights on"], robot_types=["nao", "elektron"]),
    RAppDescription(name="weather_reporter", keywords=["weather", "forecast"], phrases=["what's the weather"]),
    RAppDescription(name="email_reader", keywords=["email", "mail"], phrases=["read my email"]),
    RAppDescription(name="cognitive_game", keywords=["game", "play", "exercise"], phrases=["let's play"]),
    RAppDescription(name="news_reader", keywords=["news"], phrases=["what's new"]),
]


@pytest.mark.parametrize("text,rapp,params", [
    ("check if I left the lights on", "hazard_detection", {}),
    ("are the doors closed?", "hazard_detection", {}),
    ("Is the house safe?", "hazard_detection", {}),
    ("what's the weather in Warsaw", "weather_reporter", {"city": "Warsaw"}),
    ("Will it rain tomorrow in Krakow?", "weather_reporter", {"city": "Krakow"}),
    ("what is the forecast for Gdansk", "weather_reporter", {"city": "Gdansk"}),
    ("read my e-mail", "email_reader", {}),
    ("do I have new messages", "email_reader", {}),
    ("let's play a game", "cognitive_game", {}),
    ("tell me the news", "news_reader", {}),
])
def test_phrases(ctx, text, rapp, params):
    out = interpret_command(InterpretCommand(text=text, robot_type="nao", rapps=RAPPS), ctx)
    assert out.rapp == rapp and out.parameters == params


def test_unknown_and_robot_filter(ctx):
    with pytest.raises(ServiceError, match="did not understand") as e:
        interpret_command(InterpretCommand(text="make me a sandwich", robot_type="nao", rapps=RAPPS), ctx)
    assert e.value.code == "not-understood"
    only_nao = [RAppDescription(name="x", keywords=["lights"], robot_types=["nao"])]
    with pytest.raises(ServiceError, match="no application"):
        interpret_command(InterpretCommand(text="lights", robot_type="elektron", rapps=only_nao), ctx)


SLOTTED = [RAppDescription(name="lamp-patrol", keywords=["lamp"], phrases=["check the lamp in the {room}",
                                                                           "patrol the lamps"]),
           RAppDescription(name="weather_reporter", keywords=["weather"], phrases=["what's the weather"])]


@pytest.mark.parametrize("text,params", [
    ("Please check the lamp in the living room", {"room": "living room"}),
    ("check the lamp in the kitchen", {"room": "kitchen"}),
    ("patrol the lamps", {}),  # the other phrase: no slot to fill
    ("check the lamp in the", {}),  # an empty slot: the phrase does not match, the keyword does
])
def test_phrase_slots_fill_parameters(ctx, text, params):
    out = interpret_command(InterpretCommand(text=text, robot_type="nao", rapps=SLOTTED), ctx)
    assert out.rapp == "lamp-patrol" and out.parameters == params


def test_a_room_slot_takes_the_name_the_callers_home_gives_it(ctx):
    """Said or typed, "living room" is the room a home names "Living_Room"; a RApp compares names."""
    from ontology.services.home import HomeInfo, RoomSpec, UploadHomeInfo
    from agents.services import run_service
    rooms = [RoomSpec(name=n, rect=[i, 0, i + 1, 1]) for i, n in enumerate(["Living_Room", "kids-room", "hall"])]
    run_service("home_upload_info", UploadHomeInfo(info=HomeInfo(home_id="h", map_id="m", rooms=rooms)), ctx)
    for text, room in (("check the lamp in the living room", "Living_Room"), ("check the lamp in the kids room",
                       "kids-room"), ("check the lamp in the Hall", "hall"), ("check the lamp in the garage", "garage")):
        out = interpret_command(InterpretCommand(text=text, robot_type="nao", rapps=SLOTTED), ctx)
        assert out.parameters == {"room": room}, text


def test_a_slotted_phrase_scores_like_a_phrase(ctx):
    out = interpret_command(InterpretCommand(text="check the lamp in the hall", robot_type="nao", rapps=SLOTTED), ctx)
    assert out.score == 4 and "check the lamp in the {room}" in out.matched
