"""Information services: weather (current, forecast) and news."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action

GROUP = "information"


class CurrentWeather(Content):
    city: str
    temperature_c: float
    description: str
    humidity: int
    wind_kmh: float


@action("weather_report_current", ontology="platform", reply=CurrentWeather, group=GROUP, idempotent=True)
class WeatherCurrent(ServiceRequest):
    """The current weather in a city (offline provider)."""

    city: str = Field(min_length=1)


class ForecastDay(Content):
    day: int  # days from today
    high_c: float
    low_c: float
    description: str


class Forecast(Content):
    city: str
    days: list[ForecastDay]


@action("weather_report_forecast", ontology="platform", reply=Forecast, group=GROUP, idempotent=True)
class WeatherForecast(ServiceRequest):
    """The weather forecast of a city for the next `days` days (offline provider)."""

    city: str = Field(min_length=1)
    days: int = Field(default=3, ge=1, le=10)


class NewsStory(Content):
    title: str
    topic: str
    summary: str
    date: str


class NewsReply(Content):
    stories: list[NewsStory]


@action("news_explore", ontology="platform", reply=NewsReply, group=GROUP, idempotent=True)
class NewsExplore(ServiceRequest):
    """News stories (offline provider) matching keywords or a topic."""

    keywords: list[str] = []
    topic: str = ""
    max_stories: int = Field(default=5, ge=1, le=50)


# ------------------------------------------------------------------ geolocalization
class Location(Content):
    city: str
    country: str
    country_code: str
    latitude: float
    longitude: float
    timezone: str
    source: str  # what answered: "ip-table", "timezone" or "platform" (where the Platform is set to be)


@action("geolocation", ontology="platform", reply=Location, group=GROUP, idempotent=True)
class Geolocate(ServiceRequest):
    """Where an IP address is (`ip`), where a time zone's principal city is (`timezone`, e.g.
    "Europe/Warsaw"), or, with neither, where the Platform serving the robot is."""

    ip: str = Field(default="", max_length=45)
    timezone: str = Field(default="", max_length=64)
