"""The request behind every typed SDK call (rapps/sdk/calls.py): the fields given (UNSET ones left
to the model's defaults) become the registered request model; the reply model comes back."""
from __future__ import annotations

from typing import Any, Callable

from ontology.registry import Progress, lookup


class _Unset:
    def __repr__(self) -> str:
        return "UNSET"


UNSET: Any = _Unset()  # "not given": the request model's own default applies


class _Calls:
    def __init__(self, agent: Any, address: str, ontology: str, timeout: float,
                 extra: dict[str, Any] | None = None):
        self._agent, self._address, self._ontology = agent, address, ontology
        self._timeout, self._extra = timeout, extra or {}

    async def _call(self, action: str, fields: dict[str, Any], timeout: float | None,
                    feedback: Callable[[Progress], Any] | None = None, to: str | None = None) -> Any:
        """`feedback(Progress)`: asks for progress informs (long motions send them); cancelling the
        awaiting task cancels the action where it runs. `to`: another agent serving the same
        ontology (a Platform replica) instead of the proxy's own. Returns the action's reply model
        (a Content; the generated method states which)."""
        model = lookup(self._ontology, action)
        given = {k: v for k, v in fields.items() if v is not UNSET}
        for k, v in self._extra.items():
            if k in model.model_fields:
                given.setdefault(k, v)
        return await self._agent.request(to or self._address, model(**given), timeout=timeout or self._timeout,
                                         on_feedback=feedback)
