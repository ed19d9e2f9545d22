"""A minimal Chrome DevTools Protocol client for the book's browser test.

One headless Chromium is started with ``--remote-debugging-pipe``: the
protocol's JSON messages, each ending in a NUL byte, travel over the child's
file descriptors 3 (to Chromium) and 4 (from Chromium). That needs no
websocket library, no free TCP port and no network. :class:`Browser` opens
one tab and visits pages one after another in it, which is far faster than a
Chromium process per page (start-up is most of the cost of a small page).

What a visit records:

* every console message of level error (``console.error``, ``console.assert``),
  every uncaught exception, and every error the browser logs itself (a
  resource that failed to load, a blocked request): ``Runtime`` and ``Log``
  domain events;
* whatever the ``probe`` JavaScript expression evaluates to (a promise is
  awaited), after the page's load event.
"""
from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import subprocess
import time
from pathlib import Path
from typing import Any

__all__ = ["Browser", "BrowserError"]


class BrowserError(RuntimeError):
    """Chromium died, answered with a protocol error, or did not answer in time."""


class Browser:
    """A headless Chromium driven over the DevTools pipe; use as a context manager.

    >>> with Browser(["/usr/bin/chromium", "--headless", ...]) as b:  # doctest: +SKIP
    ...     visit = b.visit(Path("book/index.html").as_uri(), "document.title")
    ...     visit["value"], visit["errors"]
    """

    def __init__(self, argv: list[str], log: Path | None = None, timeout: float = 60.0) -> None:
        self.timeout = timeout
        to_chrome_r, self._to_chrome = os.pipe()
        self._from_chrome, from_chrome_w = os.pipe()

        def pipe_to_fds_3_and_4() -> None:  # runs in the child, between fork and exec
            # Move both ends above 4 first: one of them may itself be fd 3 or 4.
            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_chrome_r, from_chrome_w)]
            os.dup2(high[0], 3)  # dup2 makes 3 and 4 inheritable; the rest stay close-on-exec
            os.dup2(high[1], 4)

        self._log = open(log, "wb") if log else subprocess.DEVNULL
        self.proc = subprocess.Popen(
            [argv[0], "--remote-debugging-pipe", *argv[1:], "about:blank"], close_fds=False,
            preexec_fn=pipe_to_fds_3_and_4, stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log,
        )
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=self.session)

    # ------------------------------------------------------------ protocol

    def _send(self, method: str, params: dict | None, session: str | None) -> int:
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        data = json.dumps(message).encode() + b"\0"
        while data:
            data = data[os.write(self._to_chrome, data):]
        return self._next_id

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError("Chromium did not answer in time")
            ready, _, _ = select.select([self._from_chrome], [], [], left)
            if ready:
                chunk = os.read(self._from_chrome, 1 << 20)
                if not chunk:
                    raise BrowserError(f"Chromium closed the pipe (exit {self.proc.poll()})")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def call(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float | None = None) -> dict:
        """Send one command and return its result; events that arrive meanwhile are kept."""
        wanted = self._send(method, params, session)
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            message = self._receive(deadline)
            if message.get("id") != wanted:
                self._events.append(message)
                continue
            if "error" in message:
                raise BrowserError(f"{method}: {message['error']}")
            return message.get("result", {})

    def _wait_for(self, method: str, count: int, deadline: float) -> None:
        """Read messages until ``count`` events ``method`` of our tab have arrived since the visit began."""
        def seen() -> int:
            return sum(e.get("method") == method and e.get("sessionId") == self.session for e in self._events)

        while seen() < count:
            self._events.append(self._receive(deadline))

    # ------------------------------------------------------------ pages

    def set_viewport(self, width: int, height: int) -> None:
        """Emulate a window of ``width`` x ``height`` CSS pixels."""
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, self.session)

    def add_init_script(self, source: str) -> None:
        """Run ``source`` in every page loaded from now on, before the page's own scripts."""
        self.call("Page.addScriptToEvaluateOnNewDocument", {"source": source}, self.session)

    def evaluate(self, expression: str, timeout: float | None = None) -> Any:
        """The JSON value of ``expression`` in the page (a promise is awaited)."""
        result = self.call("Runtime.evaluate", {"expression": expression, "awaitPromise": True,
                                                "returnByValue": True}, self.session, timeout)
        if "exceptionDetails" in result:
            raise BrowserError(f"probe failed: {_describe_exception(result['exceptionDetails'])}")
        return result["result"].get("value")

    def _navigate(self, url: str) -> None:
        navigated = self.call("Page.navigate", {"url": url}, self.session)
        if navigated.get("errorText"):
            raise BrowserError(f"{url}: {navigated['errorText']}")

    def visit(self, url: str, probe: str = "null", timeout: float | None = None,
              screenshot: Path | None = None) -> dict:
        """Load ``url``, wait for its load event, evaluate ``probe``; return its value and the errors.

        The tab then goes to ``about:blank``, and what is logged until that has
        loaded still counts for ``url`` (a favicon or a font that fails after
        the load event). ``screenshot``: save a PNG of the window there first.
        """
        self._events.clear()
        deadline = time.monotonic() + (timeout or self.timeout)
        self._navigate(url)
        self._wait_for("Page.loadEventFired", 1, deadline)
        value = self.evaluate(probe, timeout=max(1.0, deadline - time.monotonic()))
        if screenshot is not None:
            shot = self.call("Page.captureScreenshot", {"format": "png"}, self.session)
            screenshot.write_bytes(base64.b64decode(shot["data"]))
        self._navigate("about:blank")
        self._wait_for("Page.loadEventFired", 2, time.monotonic() + self.timeout)
        mine = [e for e in self._events if e.get("sessionId") == self.session]
        return {"value": value, "errors": _errors(mine)}

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                try:
                    self._send("Browser.close", None, None)
                    self.proc.wait(timeout=10)
                except (OSError, subprocess.TimeoutExpired):
                    self.proc.kill()
                    self.proc.wait()
        finally:
            os.close(self._to_chrome)
            os.close(self._from_chrome)
            if self._log is not subprocess.DEVNULL:
                self._log.close()

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _describe_exception(details: dict) -> str:
    exception = details.get("exception") or {}
    text = exception.get("description") or details.get("text", "exception")
    where = details.get("url", "")
    return f"{text} ({where}:{details.get('lineNumber', 0) + 1})" if where else text


def _errors(events: list[dict]) -> list[str]:
    """The error-level console messages, uncaught exceptions and browser log errors among ``events``."""
    found = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            args = params.get("args", [])
            found.append("console.error: " + " ".join(str(a.get("value", a.get("description", ""))) for a in args))
        elif method == "Runtime.exceptionThrown":
            found.append("uncaught: " + _describe_exception(params.get("exceptionDetails", {})))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            entry = params["entry"]
            found.append(f"{entry.get('source', 'log')}: {entry.get('text', '')} {entry.get('url', '')}".rstrip())
    return found
