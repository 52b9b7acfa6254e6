"""
Open a report in real headless Chromium, check it and take a screenshot.

:class:`HeadlessChromium` drives Debian's ``chromium`` over the DevTools
protocol (a websocket; no Playwright, no browser download). It logs every
request the page makes and fails all but the file itself, so a check proves
that the report opens offline:

>>> with HeadlessChromium() as browser:                         # doctest: +SKIP
...     page = browser.open("out/demo/report.html")
...     page.external_requests, page.console_errors, page.broken_images
...     browser.screenshot("docs/report.png")

From the shell::

    python -m valvediag.report.browser out/demo/report.html --screenshot docs/report.png

Install the browser with ``scripts/install_chromium.sh`` (``apt-get install
-y chromium``). Chromium runs with ``--headless --no-sandbox --disable-gpu``,
no QUIC, first-run, background networking, component updates or sync, its
host resolver mapped to nothing, and a throw-away profile.
"""
from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["HeadlessChromium", "PageCheck", "find_chromium", "CHROMIUM_FLAGS"]

#: Command-line flags of the browser (plus ``--user-data-dir`` and the port).
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--disable-extensions",
                  "--disable-default-apps", "--no-default-browser-check", "--mute-audio",
                  "--hide-scrollbars", "--host-resolver-rules=MAP * ~NOTFOUND")

_CHECKS_JS = r"""(() => {
  const imgs = Array.from(document.images).map(i => ({src: i.currentSrc.slice(0, 120),
      complete: i.complete, naturalWidth: i.naturalWidth}));
  const svgs = Array.from(document.querySelectorAll("svg")).filter(s => !s.closest("svg svg") &&
      !(s.parentElement && s.parentElement.closest("svg"))).map(s => {
    const r = s.getBoundingClientRect();
    let bb = {width: 0, height: 0};
    try { bb = s.getBBox(); } catch (e) {}
    return {w: r.width, h: r.height, bw: bb.width, bh: bb.height,
            visible: !!(s.offsetParent || s.getClientRects().length),
            cls: s.getAttribute("class") || ""};
  });
  return {title: document.title, ids: Array.from(document.querySelectorAll("[id]")).map(e => e.id),
          images: imgs, svgs: svgs, height: document.documentElement.scrollHeight,
          text_length: document.body ? document.body.innerText.length : 0};
})()"""


def find_chromium() -> str:
    """Path of the Chromium binary: ``$CHROMIUM``, ``/usr/bin/chromium`` or on the PATH.

    Raises
    ------
    FileNotFoundError
        None found; the message says how to install it.
    """
    for exe in (os.environ.get("CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                shutil.which("chromium-browser")):
        if exe and os.path.isfile(exe) and os.access(exe, os.X_OK):
            return exe
    raise FileNotFoundError("Chromium not found: run scripts/install_chromium.sh "
                            "(apt-get install -y chromium) or set CHROMIUM=/path/to/chromium")


@dataclass(frozen=True)
class PageCheck:
    """What a page did when it was opened.

    Attributes
    ----------
    url : str
        The page's ``file://`` URL.
    requests : tuple of str
        Every URL the page requested (the file itself included), in order.
    external_requests : tuple of str
        Requests other than the file itself, ``data:`` and ``about:`` URLs;
        each was failed by the browser. Empty for a self-contained page.
    console_errors : tuple of str
        Console errors, uncaught exceptions and error log entries.
    dialogs : tuple of str
        Messages of ``alert``/``confirm``/``prompt`` dialogs (dismissed).
    images : tuple of dict
        ``src, complete, naturalWidth`` of every ``<img>``.
    svgs : tuple of dict
        Outermost ``<svg>`` elements: ``w, h`` (box) and ``bw, bh`` (drawn
        content) [CSS px], ``visible``, ``cls``.
    ids : tuple of str
        Every element id.
    title : str
        The document title.
    height : float
        Height of the document [CSS px].
    load_s : float
        Time to the load event [s].
    """

    url: str
    requests: tuple[str, ...] = ()
    external_requests: tuple[str, ...] = ()
    console_errors: tuple[str, ...] = ()
    dialogs: tuple[str, ...] = ()
    images: tuple[dict, ...] = ()
    svgs: tuple[dict, ...] = ()
    ids: tuple[str, ...] = ()
    title: str = ""
    height: float = 0.0
    load_s: float = 0.0

    @property
    def broken_images(self) -> list[str]:
        """``src`` of every image that did not load (natural width 0)."""
        return [i["src"] for i in self.images if not i["complete"] or i["naturalWidth"] <= 0]

    @property
    def blank_svgs(self) -> list[dict]:
        """Visible SVGs with no size or nothing drawn (a flat line still counts as drawn)."""
        return [s for s in self.svgs if s["visible"] and
                (s["w"] <= 0 or s["h"] <= 0 or (s["bw"] <= 0 and s["bh"] <= 0))]

    @property
    def ok(self) -> bool:
        """No external request, console error, dialog, broken image or blank SVG."""
        return not (self.external_requests or self.console_errors or self.dialogs or
                    self.broken_images or self.blank_svgs)

    def to_json(self) -> dict:
        """The findings as plain JSON values (without the ids)."""
        return {"url": self.url, "ok": self.ok, "requests": list(self.requests),
                "external_requests": list(self.external_requests),
                "console_errors": list(self.console_errors), "dialogs": list(self.dialogs),
                "images": len(self.images), "broken_images": self.broken_images,
                "svgs": len(self.svgs), "blank_svgs": len(self.blank_svgs),
                "title": self.title, "height": self.height, "load_s": round(self.load_s, 3)}


class CDPError(RuntimeError):
    """The browser answered a DevTools command with an error, or did not answer."""


@dataclass
class _Session:
    events: list = field(default_factory=list)


class HeadlessChromium:
    """A headless Chromium with one tab, driven over the DevTools protocol.

    Parameters
    ----------
    executable : str, optional
        The browser (default :func:`find_chromium`).
    width, height : int
        Window size [CSS px].
    timeout : float
        Longest wait for the browser to start, a page to load or a command
        to answer [s].

    Notes
    -----
    Use as a context manager; the browser and its temporary profile are
    removed on exit. Every request of the page goes through the protocol's
    request interception: the page's own ``file://`` URL (and ``data:``)
    continue, everything else fails with ``BlockedByClient`` and is listed
    in :attr:`PageCheck.external_requests`.
    """

    def __init__(self, executable: str | None = None, *, width: int = 1400, height: int = 900,
                 timeout: float = 60.0):
        self.executable = executable or find_chromium()
        self.width, self.height, self.timeout = int(width), int(height), float(timeout)
        self._ids = itertools.count(1)
        self.proc = None
        self.ws = None
        self.session = None
        self.profile = None
        self._events: list[dict] = []

    # -- process and protocol -------------------------------------------
    def __enter__(self) -> HeadlessChromium:
        from websockets.sync.client import connect

        self.profile = tempfile.mkdtemp(prefix="valvediag-chromium-")
        cmd = [self.executable, *CHROMIUM_FLAGS, f"--user-data-dir={self.profile}",
               "--remote-debugging-port=0", f"--window-size={self.width},{self.height}",
               "about:blank"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     stdin=subprocess.DEVNULL)
        try:
            port_file = Path(self.profile) / "DevToolsActivePort"
            deadline = time.monotonic() + self.timeout
            while True:
                if port_file.is_file():
                    lines = port_file.read_text().split()
                    if len(lines) >= 2:
                        break
                if self.proc.poll() is not None:
                    raise CDPError(f"{self.executable} exited with {self.proc.returncode} "
                                   "before opening its DevTools port")
                if time.monotonic() > deadline:
                    raise CDPError(f"{self.executable} did not open its DevTools port in "
                                   f"{self.timeout:g} s")
                time.sleep(0.05)
            self.ws = connect(f"ws://127.0.0.1:{lines[0]}{lines[1]}", max_size=None,
                              open_timeout=self.timeout, proxy=None)
            target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
            self.session = self.send("Target.attachToTarget",
                                     {"targetId": target, "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log", "Network"):
                self.send(f"{domain}.enable", session=True)
            self.send("Fetch.enable", {"patterns": [{"urlPattern": "*"}]}, session=True)
            self.send("Emulation.setDeviceMetricsOverride",
                      {"width": self.width, "height": self.height, "deviceScaleFactor": 1,
                       "mobile": False}, session=True)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self.ws is not None:
                try:
                    self.ws.send(json.dumps({"id": next(self._ids), "method": "Browser.close"}))
                except Exception:
                    pass
                self.ws.close()
        finally:
            if self.proc is not None:
                try:
                    self.proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(timeout=10)
            if self.profile:
                shutil.rmtree(self.profile, ignore_errors=True)

    def _handle(self, msg: dict) -> None:
        """Keep an event; answer paused requests at once (the page waits for them)."""
        method = msg.get("method", "")
        params = msg.get("params", {})
        if method == "Fetch.requestPaused":
            url = params["request"]["url"]
            allowed = url.split("#", 1)[0] == self._page_url or url.startswith(("data:", "about:"))
            if allowed:
                self._post("Fetch.continueRequest", {"requestId": params["requestId"]})
            else:
                self._post("Fetch.failRequest", {"requestId": params["requestId"],
                                                 "errorReason": "BlockedByClient"})
        elif method == "Page.javascriptDialogOpening":
            self._post("Page.handleJavaScriptDialog", {"accept": False})
        self._events.append(msg)

    _page_url = ""

    def _post(self, method: str, params: dict | None = None) -> int:
        i = next(self._ids)
        msg = {"id": i, "method": method, "params": params or {}}
        if self.session:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        return i

    def send(self, method: str, params: dict | None = None, *, session: bool = False) -> dict:
        """Send a DevTools command and wait for its answer.

        Parameters
        ----------
        method : str
            E.g. ``"Page.navigate"``.
        params : dict, optional
            Its parameters.
        session : bool
            Send to the tab (True) or to the browser.

        Returns
        -------
        dict
            The command's result.
        """
        i = next(self._ids)
        msg = {"id": i, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        deadline = time.monotonic() + self.timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise CDPError(f"{method}: no answer in {self.timeout:g} s")
            reply = json.loads(self.ws.recv(timeout=left))
            if reply.get("id") == i:
                if "error" in reply:
                    raise CDPError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            if "method" in reply:
                self._handle(reply)

    def _pump(self, seconds: float, until=None) -> None:
        """Handle events for ``seconds``, or until ``until(event)`` is true."""
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                msg = json.loads(self.ws.recv(timeout=left))
            except TimeoutError:
                return
            if "method" in msg:
                self._handle(msg)
                if until is not None and until(msg):
                    return

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-able values).

        Parameters
        ----------
        expression : str
            JavaScript.
        """
        res = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                              "awaitPromise": True}, session=True)
        if "exceptionDetails" in res:
            d = res["exceptionDetails"]
            raise CDPError(f"evaluate: {d.get('exception', {}).get('description') or d.get('text')}")
        return res["result"].get("value")

    # -- pages -------------------------------------------------------------
    def open(self, path, *, settle: float = 0.5) -> PageCheck:
        """Load a local HTML file and report what it did.

        Parameters
        ----------
        path : str or path-like
            The file.
        settle : float
            Quiet time after the load event to catch late requests [s].

        Returns
        -------
        PageCheck
        """
        url = Path(path).resolve().as_uri()
        self._page_url = url
        first = len(self._events)
        t0 = time.monotonic()
        self.send("Page.navigate", {"url": url}, session=True)
        loaded = [e for e in self._events[first:] if e.get("method") == "Page.loadEventFired"]
        if not loaded:
            self._pump(self.timeout, until=lambda e: e.get("method") == "Page.loadEventFired")
        load_s = time.monotonic() - t0
        self._pump(settle)
        events = self._events[first:]
        requests, errors, dialogs = [], [], []
        for e in events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Network.requestWillBeSent":
                requests.append(p["request"]["url"])
            elif m == "Fetch.requestPaused" and p["request"]["url"] not in requests:
                requests.append(p["request"]["url"])
            elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                errors.append("console: " + " ".join(str(a.get("value", a.get("description", "")))
                                                     for a in p.get("args", [])))
            elif m == "Runtime.exceptionThrown":
                d = p.get("exceptionDetails", {})
                errors.append("exception: " + (d.get("exception", {}).get("description")
                                               or d.get("text", "")))
            elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                errors.append(f"log: {p['entry'].get('text', '')} {p['entry'].get('url', '')}"
                              .strip())
            elif m == "Page.javascriptDialogOpening":
                dialogs.append(f"{p.get('type')}: {p.get('message')}")
        requests = list(dict.fromkeys(requests))   # the interception and the log both see it
        external = [u for u in requests if u.split("#", 1)[0] != url
                    and not u.startswith(("data:", "about:"))]
        info = self.evaluate(_CHECKS_JS) or {}
        return PageCheck(url=url, requests=tuple(requests), external_requests=tuple(external),
                         console_errors=tuple(errors), dialogs=tuple(dialogs),
                         images=tuple(info.get("images", ())), svgs=tuple(info.get("svgs", ())),
                         ids=tuple(info.get("ids", ())), title=info.get("title", ""),
                         height=float(info.get("height", 0)), load_s=load_s)

    def screenshot(self, path, *, selector: str | None = None, full_page: bool = False,
                   max_height: int = 16000) -> Path:
        """Save a PNG of the page: the viewport, the whole page or one element.

        Parameters
        ----------
        path : str or path-like
            Output PNG.
        selector : str, optional
            CSS selector of the element to capture (scrolled into view).
        full_page : bool
            Capture the whole document (at most ``max_height`` px tall).
        max_height : int
            Cap of a full-page capture [CSS px].

        Returns
        -------
        pathlib.Path
        """
        params: dict = {"format": "png"}
        if selector is not None:
            box = self.evaluate(
                "(() => { const e = document.querySelector(%s); if (!e) return null;"
                " e.scrollIntoView(); const r = e.getBoundingClientRect();"
                " return {x: r.left + window.scrollX, y: r.top + window.scrollY,"
                " w: r.width, h: r.height}; })()" % json.dumps(selector))
            if box is None:
                raise CDPError(f"screenshot: no element matches {selector!r}")
            params.update(clip={"x": box["x"], "y": box["y"], "width": box["w"],
                                "height": min(box["h"], max_height), "scale": 1},
                          captureBeyondViewport=True)
        elif full_page:
            h = min(float(self.evaluate("document.documentElement.scrollHeight")), max_height)
            params.update(clip={"x": 0, "y": 0, "width": self.width, "height": h, "scale": 1},
                          captureBeyondViewport=True)
        data = self.send("Page.captureScreenshot", params, session=True)["data"]
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(data))
        return path


def main(argv=None) -> int:
    """``python -m valvediag.report.browser REPORT [--screenshot PNG]``: check a report.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 when the page is clean (see :attr:`PageCheck.ok`), 1 otherwise.
    """
    import argparse

    ap = argparse.ArgumentParser(prog="python -m valvediag.report.browser",
                                 description="Open an HTML report in headless Chromium, check "
                                             "that it loads nothing from outside and shows "
                                             "without errors, and optionally save a screenshot.")
    ap.add_argument("report", help="the HTML file")
    ap.add_argument("--screenshot", metavar="PNG", help="save a PNG of the page")
    ap.add_argument("--width", type=int, default=1400, help="window width [px] (default 1400)")
    ap.add_argument("--height", type=int, default=900, help="window height [px] (default 900)")
    ap.add_argument("--full-page", action="store_true", help="capture the whole page")
    ap.add_argument("--selector", help="capture only this element (CSS selector)")
    args = ap.parse_args(argv)
    with HeadlessChromium(width=args.width, height=args.height) as browser:
        page = browser.open(args.report)
        if args.screenshot:
            browser.screenshot(args.screenshot, selector=args.selector, full_page=args.full_page)
    print(json.dumps(page.to_json(), indent=1))
    return 0 if page.ok else 1


if __name__ == "__main__":   # pragma: no cover
    raise SystemExit(main())
