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
    keywords: list[str] = []
    topic: str = ""
    max_stories: int = Field(default=5, ge=1, le=50)
