"""Weather reporter: fetch current weather and forecast, speak them, report them to the user."""
from rapps.sdk import FSM, Step, Task


class WeatherTask(Task):
    def build(self):
        fsm = FSM("weather", initial="fetch")
        fsm.add_state("fetch", Step(self.fetch))
        fsm.add_state("tell", Step(self.tell), final=True)
        fsm.add_transition("fetch", "tell")
        return fsm

    async def fetch(self, memory):
        city = str(self.params.get("city") or "Warsaw")
        memory["now"] = await self.platform.weather_report_current(city=city)
        memory["forecast"] = await self.platform.weather_report_forecast(city=city,
                                                                        days=int(self.params.get("days", 3)))

    async def tell(self, memory):
        now, forecast = memory["now"], memory["forecast"]
        lines = [f"In {now.city} it is {now.temperature_c:.0f} degrees and {now.description}, "
                 f"wind {now.wind_kmh:.0f} kilometres per hour."]
        for day in forecast.days:
            when = "Tomorrow" if day.day == 1 else f"In {day.day} days"
            lines.append(f"{when}: {day.description}, from {day.low_c:.0f} to {day.high_c:.0f} degrees.")
        spoken = await self.say(*lines)
        await self.report(" ".join(lines) + ("" if spoken else " (I cannot speak, so I wrote it.)"))
