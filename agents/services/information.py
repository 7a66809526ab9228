"""Weather and news behind provider interfaces; the offline providers read local JSON files."""
from __future__ import annotations

import json
from abc import ABC, abstractmethod
from pathlib import Path

from ontology.services.information import (
    CurrentWeather, Forecast, ForecastDay, NewsExplore, NewsReply, NewsStory, WeatherCurrent, WeatherForecast,
)
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError


class WeatherProvider(ABC):
    @abstractmethod
    def current(self, city: str) -> CurrentWeather: ...

    @abstractmethod
    def forecast(self, city: str, days: int) -> Forecast: ...


class NewsProvider(ABC):
    @abstractmethod
    def stories(self, keywords: list[str], topic: str, limit: int) -> list[NewsStory]: ...


class LocalWeather(WeatherProvider):
    def __init__(self, path: Path) -> None:
        self.data = {k.lower(): v for k, v in json.loads(path.read_text()).items()}

    def _city(self, city: str) -> dict:
        try:
            return self.data[city.strip().lower()]
        except KeyError:
            known = ", ".join(v["city"] for v in self.data.values())
            raise ServiceError(f"no weather data for city {city!r} (known: {known})", ErrorCode.UNKNOWN_CITY) from None

    def current(self, city: str) -> CurrentWeather:
        d = self._city(city)
        return CurrentWeather(city=d["city"], **d["current"])

    def forecast(self, city: str, days: int) -> Forecast:
        d = self._city(city)
        return Forecast(city=d["city"], days=[ForecastDay(**f) for f in d["forecast"][:days]])


class LocalNews(NewsProvider):
    def __init__(self, path: Path) -> None:
        self.items = [NewsStory(**s) for s in json.loads(path.read_text())]

    def stories(self, keywords: list[str], topic: str, limit: int) -> list[NewsStory]:
        kws = [k.lower() for k in keywords]
        out = [s for s in self.items
               if (not topic or s.topic == topic.lower())
               and (not kws or any(k in (s.title + " " + s.summary).lower() for k in kws))]
        return out[:limit]


def weather(ctx: ServiceContext) -> WeatherProvider:
    return ctx.state.store("weather", lambda: LocalWeather(ctx.state.data_dir / "weather.json"))


def news(ctx: ServiceContext) -> NewsProvider:
    return ctx.state.store("news", lambda: LocalNews(ctx.state.data_dir / "news.json"))


def weather_current(req: WeatherCurrent, ctx: ServiceContext) -> CurrentWeather:
    return weather(ctx).current(req.city)


def weather_forecast(req: WeatherForecast, ctx: ServiceContext) -> Forecast:
    return weather(ctx).forecast(req.city, req.days)


def news_explore(req: NewsExplore, ctx: ServiceContext) -> NewsReply:
    return NewsReply(stories=news(ctx).stories(req.keywords, req.topic, req.max_stories))
