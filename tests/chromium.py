"""A small driver for headless Chromium over the DevTools protocol, on a pipe.

Chromium started with ``--remote-debugging-pipe`` reads protocol commands
(JSON, each ended by a NUL byte) from its file descriptor 3 and writes answers
and events to descriptor 4, so no port, no websocket and no extra package are
needed. One browser serves many pages; :meth:`Browser.open` gives a
:class:`Page` attached to a new tab, which records console messages,
exceptions and network requests from the start.

The browser runs with no network: every host resolves to nothing and the proxy
is unreachable, so a page that needs the network shows it as a failed request.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Self

TIMEOUT = 20.0


def find_chromium() -> str | None:
    """The Chromium executable: ``$CHROMIUM``, else ``chromium`` or ``chromium-browser`` on PATH."""
    if os.environ.get("CHROMIUM"):
        return os.environ["CHROMIUM"]
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class ProtocolError(RuntimeError):
    pass


class Browser:
    """A headless Chromium process and its protocol pipe."""

    def __init__(self, executable: str | None = None, width: int = 1000, height: int = 1100):
        executable = executable or find_chromium()
        if executable is None:
            raise FileNotFoundError("chromium not found")
        self.profile = tempfile.mkdtemp(prefix="jackbox-chromium-")
        # The protocol wants exactly fds 3 (commands in) and 4 (answers out) in chromium. The
        # child's ends go to fds >= 20 here, and bash (dash takes single-digit fds only) moves
        # them to 3 and 4 and runs chromium.
        cmd_r, self._cmd_w = os.pipe()
        self._resp_r, resp_w = os.pipe()
        child_r = fcntl.fcntl(cmd_r, fcntl.F_DUPFD_CLOEXEC, 20)
        child_w = fcntl.fcntl(resp_w, fcntl.F_DUPFD_CLOEXEC, 20)
        os.close(cmd_r)
        os.close(resp_w)
        shell = f'exec "$0" "$@" 3<&{child_r} 4>&{child_w} {child_r}<&- {child_w}>&-'
        args = [executable, "--headless", "--remote-debugging-pipe", "--no-sandbox", "--disable-gpu",
                "--no-first-run", "--no-default-browser-check", "--disable-extensions",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--mute-audio", "--hide-scrollbars", f"--user-data-dir={self.profile}",
                f"--window-size={width},{height}",
                # no network: nothing resolves and the proxy is a closed port
                "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9",
                "about:blank"]
        self.proc = subprocess.Popen(["bash", "-c", shell, *args], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     pass_fds=(child_r, child_w))
        os.close(child_r)
        os.close(child_w)
        self._next_id = 0
        self._lock = threading.Lock()
        self._answers: dict[int, queue.Queue] = {}
        self._listeners: dict[str, list] = {}
        self._stderr: list[bytes] = []
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._drain_stderr, daemon=True).start()
        self.version = self.send("Browser.getVersion")

    # --- protocol ------------------------------------------------------------------------

    def _read(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._resp_r, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                for q in list(self._answers.values()):
                    q.put({"error": {"message": "chromium closed the pipe"}})
                return
            buf += chunk
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg = json.loads(raw)
                if "id" in msg:
                    q = self._answers.get(msg["id"])
                    if q is not None:
                        q.put(msg)
                else:
                    for listener in list(self._listeners.get(msg.get("sessionId", ""), [])):
                        listener(msg)

    def _drain_stderr(self) -> None:
        for line in self.proc.stderr:
            self._stderr.append(line)

    def send(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = TIMEOUT) -> dict:
        with self._lock:
            self._next_id += 1
            mid = self._next_id
            self._answers[mid] = queue.Queue()
        msg = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        try:
            answer = self._answers[mid].get(timeout=timeout)
        except queue.Empty:
            raise ProtocolError(f"{method}: no answer in {timeout} s") from None
        finally:
            self._answers.pop(mid, None)
        if "error" in answer:
            raise ProtocolError(f"{method}: {answer['error'].get('message')}")
        return answer.get("result", {})

    def listen(self, session: str, callback) -> None:
        self._listeners.setdefault(session, []).append(callback)

    def open(self, url: str | Path, width: int = 1000, height: int = 1100) -> Page:
        """A new tab showing ``url`` (a path is opened as file://), loaded."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, target, session)
        page.load(Path(url).resolve().as_uri() if isinstance(url, Path) else url, width, height)
        return page

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=5)
        except (ProtocolError, OSError):
            pass    # it is going away either way; wait() below makes sure
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._cmd_w, self._resp_r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Page:
    """One tab: what it logged, what it requested, and a few ways to act on it."""

    def __init__(self, browser: Browser, target: str, session: str):
        self.browser, self.target, self.session = browser, target, session
        self.console: list[tuple[str, str]] = []     #: (level, text) of console calls and log entries
        self.exceptions: list[str] = []
        self.requests: list[str] = []                #: every URL the page asked for
        self.failed: list[str] = []                  #: URLs that failed to load, with the reason
        self._loaded = threading.Event()
        browser.listen(session, self._event)

    def send(self, method: str, params: dict | None = None, timeout: float = TIMEOUT) -> dict:
        return self.browser.send(method, params, self.session, timeout)

    def _event(self, msg: dict) -> None:
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            self.console.append((p.get("type", ""), text))
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            self.exceptions.append(d.get("exception", {}).get("description") or d.get("text", ""))
        elif method == "Log.entryAdded":
            e = p.get("entry", {})
            self.console.append((e.get("level", ""), e.get("text", "")))
        elif method == "Network.requestWillBeSent":
            self.requests.append(p.get("request", {}).get("url", ""))
        elif method == "Network.loadingFailed":
            self.failed.append(f"{p.get('errorText')} ({p.get('requestId')})")
        elif method == "Page.loadEventFired":
            self._loaded.set()

    def load(self, url: str, width: int, height: int) -> None:
        for domain in ("Runtime", "Log", "Network", "Page"):
            self.send(f"{domain}.enable")
        self.send("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
        self._loaded.clear()
        self.send("Page.navigate", {"url": url})
        if not self._loaded.wait(TIMEOUT):
            raise ProtocolError(f"{url}: no load event in {TIMEOUT} s")

    @property
    def errors(self) -> list[str]:
        """Console errors and uncaught exceptions."""
        return [text for level, text in self.console if level in ("error", "assert")] + self.exceptions

    def eval(self, expression: str, timeout: float = TIMEOUT):
        """The value of a JavaScript expression (awaited when it is a promise)."""
        result = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                "awaitPromise": True}, timeout)
        if "exceptionDetails" in result:
            d = result["exceptionDetails"]
            raise ProtocolError(f"{expression[:80]}: {d.get('exception', {}).get('description') or d.get('text')}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = TIMEOUT, interval: float = 0.05):
        """Poll until the expression is truthy; return its value."""
        end = time.monotonic() + timeout
        while True:
            value = self.eval(expression)
            if value:
                return value
            if time.monotonic() > end:
                raise ProtocolError(f"timed out waiting for {expression[:100]}")
            time.sleep(interval)

    def click(self, x: float, y: float) -> None:
        """A real left click (press and release) at page coordinates."""
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.send("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left",
                                                   "clickCount": 0 if kind == "mouseMoved" else 1})

    def screenshot(self) -> bytes:
        """The visible page as PNG bytes."""
        return base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])

    def close(self) -> None:
        try:
            self.browser.send("Target.closeTarget", {"targetId": self.target}, timeout=5)
        except ProtocolError:
            pass
