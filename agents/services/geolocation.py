"""Geolocalization (paper 000 sec. 5.3, an information service) behind a provider interface; the offline
provider answers without the internet:

- an IP address: from a table of address blocks (data/geolocation.json, the most specific block
  first); a private, loopback or link-local address is on the Platform's own network, so it is where
  the Platform is set to be; a public address the table does not hold is unknown (not_found);
- a time zone: its principal city and coordinates from the IANA time zone database's zone1970.tab and
  iso3166.tab, as the PyPI package tzdata (Apache-2.0) ships them;
- neither: where the Platform is set to be (the table's "platform" entry).
"""
from __future__ import annotations

import ipaddress
import json
from abc import ABC, abstractmethod
from functools import lru_cache
from importlib import resources
from pathlib import Path

from ontology.errors import ErrorCode
from ontology.services.information import Geolocate, Location

from .context import ServiceContext
from .errors import ServiceError


class GeoProvider(ABC):
    @abstractmethod
    def locate(self, ip: str, timezone: str) -> Location: ...


def _coordinate(text: str, degree_digits: int) -> float:
    """ISO 6709 as zone.tab writes it: +DDMM[SS] (latitude) or +DDDMM[SS] (longitude)."""
    sign = -1.0 if text[0] == "-" else 1.0
    digits = text[1:]
    deg, rest = int(digits[:degree_digits]), digits[degree_digits:]
    minutes, seconds = int(rest[:2]), int(rest[2:4] or 0)
    return sign * (deg + minutes / 60 + seconds / 3600)


@lru_cache(maxsize=1)
def time_zones() -> dict[str, tuple[str, str, float, float]]:
    """zone -> (country code, country name, latitude, longitude) of its principal city."""
    folder = resources.files("tzdata") / "zoneinfo"
    countries = {}
    for line in (folder / "iso3166.tab").read_text(encoding="utf-8").splitlines():
        if line and not line.startswith("#"):
            code, name = line.split("\t")[:2]
            countries[code] = name
    zones = {}
    for line in (folder / "zone1970.tab").read_text(encoding="utf-8").splitlines():
        if not line or line.startswith("#"):
            continue
        codes, coords, zone = line.split("\t")[:3]
        split = max(coords.rfind("+"), coords.rfind("-"))
        lat, lon = coords[:split], coords[split:]
        code = codes.split(",")[0]
        zones[zone] = (code, countries.get(code, code), _coordinate(lat, 2), _coordinate(lon, 3))
    return zones


class OfflineGeo(GeoProvider):
    def __init__(self, path: Path) -> None:
        data = json.loads(path.read_text())
        self.platform = Location(**data["platform"], source="platform")
        self.networks = sorted(((ipaddress.ip_network(n.pop("network")), Location(**n, source="ip-table"))
                                for n in data["networks"]), key=lambda e: -e[0].prefixlen)

    def locate(self, ip: str, timezone: str) -> Location:
        if ip:
            try:
                addr = ipaddress.ip_address(ip.strip())
            except ValueError:
                raise ServiceError(f"{ip!r} is not an IP address", ErrorCode.INVALID_ARGUMENT) from None
            for net, place in self.networks:
                if addr.version == net.version and addr in net:
                    return place
            if addr.is_private or addr.is_loopback or addr.is_link_local:
                return self.platform
            raise ServiceError(f"no place known for {addr} (offline table agents/services/data/geolocation.json)",
                               ErrorCode.NOT_FOUND)
        if timezone:
            zone = time_zones().get(timezone.strip())
            if zone is None:
                raise ServiceError(f"unknown time zone {timezone!r} (IANA names such as Europe/Warsaw)",
                                   ErrorCode.NOT_FOUND)
            code, country, lat, lon = zone
            city = timezone.strip().rsplit("/", 1)[-1].replace("_", " ")
            return Location(city=city, country=country, country_code=code, latitude=round(lat, 4),
                            longitude=round(lon, 4), timezone=timezone.strip(), source="timezone")
        return self.platform


def provider(ctx: ServiceContext) -> GeoProvider:
    return ctx.state.store("geolocation", lambda: OfflineGeo(ctx.state.data_dir / "geolocation.json"))


def geolocate(req: Geolocate, ctx: ServiceContext) -> Location:
    return provider(ctx).locate(req.ip, req.timezone)
