"""`rapp store serve`: a page for RApp developers (paper 000 sec. 6.2: "the whole interaction between
the developers and the Store is possible using web interface"): every package, its versions, each
version's build per robot type (passed, failed with the reason, untested, queued, building) and
each build's log, read from the Store Agent over XMPP as any client reads it.

    page = StorePage(client, store_jid); url = await page.start()   # http://127.0.0.1:8780/
    ...; await page.stop()

The page is self-contained (no CDN) and polls /builds.json every few seconds, so builds still
running are seen to end; text from packages and logs is shown as text, never markup. It serves
127.0.0.1 by default and has no authentication: what it shows is what any client of the Store may
read (the catalogue and the builds; nothing of owners or downloads).
"""
from __future__ import annotations

import asyncio
import contextlib
import sys

from aiohttp import web

from agents.errors import RequestError
from ontology import store as S

NO_STORE = {"Cache-Control": "no-store"}


class StorePage:
    def __init__(self, client, store: str, host: str = "127.0.0.1", port: int = 8780):
        self.client, self.store, self.host, self.port = client, store, host, port
        self._runner: web.AppRunner | None = None
        self.url = ""

    async def packages(self) -> dict:
        """{"packages": [{name, description, versions: [{version, builds: [...]}]}]}, newest versions first."""
        reply = await self.client.request(self.store, S.Builds(), timeout=20.0)
        listed = {p.name: p for p in (await self.client.request(self.store, S.ListPackages(), timeout=20.0)).packages}
        out: dict[str, dict] = {}
        for b in reply.builds:
            pkg = out.setdefault(b.name, {"name": b.name, "description": getattr(listed.get(b.name), "description", ""),
                                          "listed": getattr(listed.get(b.name), "version", None), "versions": {}})
            pkg["versions"].setdefault(b.version, []).append(b.model_dump(mode="json"))
        return {"store": self.store, "packages": [
            {**p, "versions": [{"version": v, "builds": bs} for v, bs in p["versions"].items()]} for p in out.values()]}

    def _app(self) -> web.Application:
        async def index(_):
            return web.Response(text=PAGE, content_type="text/html", headers=NO_STORE)

        async def builds(_):
            try:
                return web.json_response(await self.packages(), headers=NO_STORE)
            except RequestError as e:
                raise web.HTTPBadGateway(text=f"the Store did not answer: {e.reason}")

        async def log(request):
            q = request.query
            if not all(q.get(k) for k in ("name", "version", "robot_type")):
                raise web.HTTPBadRequest(text="name, version and robot_type are needed")
            try:
                reply = await self.client.request(self.store, S.BuildLog(name=q["name"], version=q["version"],
                                                                         robot_type=q["robot_type"]), timeout=20.0)
            except RequestError as e:
                raise web.HTTPNotFound(text=e.reason)
            return web.json_response(reply.model_dump(), headers=NO_STORE)

        app = web.Application()
        app.add_routes([web.get("/", index), web.get("/builds.json", builds), web.get("/log", log)])
        return app

    async def start(self) -> str:
        self._runner = web.AppRunner(self._app(), access_log=None)
        await self._runner.setup()
        await web.TCPSite(self._runner, self.host, self.port).start()
        host, port = self._runner.addresses[0][:2]
        self.url = f"http://{host}:{port}/"
        return self.url

    async def stop(self) -> None:
        if self._runner is not None:
            with contextlib.suppress(Exception):
                await self._runner.cleanup()
            self._runner = None


async def serve_forever(client, store: str, host: str = "127.0.0.1", port: int = 8780) -> None:
    page = StorePage(client, store, host, port)
    try:
        url = await page.start()
    except OSError as e:
        raise RuntimeError(f"cannot serve on {host}:{port}: {e.strerror or e}") from None
    print(f"the Store's page for developers: {url} (Ctrl-C stops it)", file=sys.stderr, flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await page.stop()


PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>RAPP Store: packages and builds</title>
<style>
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.3em; } h2 { font-size: 1.1em; margin: 1.2em 0 0.3em; }
table { border-collapse: collapse; margin-bottom: 0.5em; }
td, th { border-bottom: 1px solid #ddd; padding: 0.25em 0.7em; text-align: left; vertical-align: top; }
.state { font-weight: 600; padding: 0 0.4em; border-radius: 3px; cursor: pointer; border: none; font: inherit; }
.passed { background: #c8f0c8; } .failed { background: #ffc9c9; } .untested { background: #eee; }
.queued, .building { background: #fff2b3; }
#log { white-space: pre-wrap; background: #f6f6f6; padding: 0.8em; max-height: 30em; overflow: auto; }
.muted { color: #777; }
</style></head><body>
<h1>RAPP Store: packages and builds</h1>
<p class="muted" id="status">loading...</p>
<div id="packages"></div>
<h2 id="log-title">Build log</h2>
<div id="log" class="muted">choose a build's state to read its log</div>
<script>
"use strict";
function el(tag, text, cls) { const e = document.createElement(tag); if (text !== undefined) e.textContent = text;
  if (cls) e.className = cls; return e; }
async function showLog(b) {
  const q = new URLSearchParams({name: b.name, version: b.version, robot_type: b.robot_type});
  const title = document.getElementById("log-title"), box = document.getElementById("log");
  title.textContent = `Build log: ${b.name} ${b.version} for ${b.robot_type}`;
  const r = await fetch("/log?" + q);
  box.className = "";
  box.textContent = r.ok ? ((await r.json()).log || "(empty)") : await r.text();
}
function render(data) {
  const root = document.getElementById("packages");
  root.replaceChildren();
  for (const p of data.packages) {
    const section = el("section"); section.dataset.package = p.name;
    const h = el("h2", p.name + " "); h.append(el("span", p.description || "", "muted")); section.append(h);
    const table = el("table"), head = el("tr");
    for (const t of ["version", "robot type", "build", "why", "took"]) head.append(el("th", t));
    table.append(head);
    for (const v of p.versions) for (const b of v.builds) {
      const tr = el("tr"); tr.dataset.version = v.version; tr.dataset.robotType = b.robot_type;
      tr.append(el("td", v.version), el("td", b.robot_type));
      const cell = el("td"), button = el("button", b.state, "state " + b.state);
      button.addEventListener("click", () => showLog(b)); cell.append(button); tr.append(cell);
      tr.append(el("td", b.reason || ""), el("td", b.ended && b.started ? (b.ended - b.started).toFixed(1) + " s" : ""));
      table.append(tr);
    }
    section.append(table); root.append(section);
  }
  document.getElementById("status").textContent =
    `${data.packages.length} packages in ${data.store}; updated ${new Date().toLocaleTimeString()}`;
}
async function refresh() {
  try { const r = await fetch("/builds.json"); if (r.ok) render(await r.json());
        else document.getElementById("status").textContent = await r.text(); }
  catch (e) { document.getElementById("status").textContent = "the page's server is gone: " + e; }
}
refresh(); setInterval(refresh, 3000);
</script></body></html>
"""
