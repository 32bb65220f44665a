"""Drive the web console in headless Chromium through its DevTools protocol (run inside a namespace).

``python -m tests.console.cdp_console DEVTOOLS_HTTP PAGE_URL KEY_FILE SCREENSHOT AGENT [AGENT ...]``: open the
page, sign in with the key, wait until the console's terminal output names every agent, press ``T``
(take off all) and ``y`` (confirm), take a screenshot, and print one JSON line: the URLs the page
requested and what it saw. The test checks the rest (the agents' states on the bus).

Chromium draws the terminal on a canvas, so the text is read where it arrives: a script added before
the page's own wraps ``WebSocket`` and keeps what the console sent, as text without escape codes.
"""

from __future__ import annotations

import base64
import itertools
import json
import re
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

from websockets.sync.client import ClientConnection, connect

RECORDER = r"""
(() => {
  window.__antalateRx = "";
  const Native = window.WebSocket;
  const decoder = new TextDecoder();
  window.WebSocket = function (url, protocols) {
    const ws = protocols === undefined ? new Native(url) : new Native(url, protocols);
    ws.addEventListener("message", (event) => {
      const text = typeof event.data === "string" ? event.data : decoder.decode(event.data);
      window.__antalateRx = (window.__antalateRx + text).slice(-400000);
    });
    return ws;
  };
  window.WebSocket.prototype = Native.prototype;
  Object.assign(window.WebSocket, {CONNECTING: 0, OPEN: 1, CLOSING: 2, CLOSED: 3});
})();
"""
ESCAPES = re.compile(r"\x1b\[[0-9;?<>=]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(\x07|\x1b\\)|\x1b[@-Z\\-_]")


class Page:
    def __init__(self, ws_url: str) -> None:
        self.ws: ClientConnection = connect(ws_url, max_size=None, open_timeout=30)
        self.ids = itertools.count(1)
        self.requests: list[str] = []
        self.js_errors: list[str] = []

    def call(self, method: str, timeout: float = 30, **params: Any) -> dict[str, Any]:
        msg_id = next(self.ids)
        self.ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            reply = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            if reply.get("id") == msg_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                result: dict[str, Any] = reply.get("result", {})
                return result
            self._event(reply)

    def _event(self, event: dict[str, Any]) -> None:
        method, params = event.get("method"), event.get("params", {})
        if method == "Network.requestWillBeSent":
            self.requests.append(params["request"]["url"])
        elif method == "Network.webSocketCreated":
            self.requests.append(params["url"])
        elif method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            self.js_errors.append(str(details.get("exception", {}).get("description") or details.get("text")))

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    def wait(self, expression: str, timeout: float, what: str) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.2)
        raise TimeoutError(f"timed out waiting for {what}")

    def screen_text(self) -> str:
        return ESCAPES.sub("", self.evaluate("window.__antalateRx || ''") or "")

    def wait_text(self, needles: list[str], timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.screen_text()
            if all(n in text for n in needles):
                return text
            time.sleep(0.3)
        raise TimeoutError(f"the console never showed {needles}; it showed:\n{self.screen_text()[-3000:]}")

    def press(self, char: str) -> None:
        code = f"Key{char.upper()}"
        modifiers = 8 if char.isupper() else 0  # Shift
        key: dict[str, Any] = {
            "key": char,
            "code": code,
            "windowsVirtualKeyCode": ord(char.upper()),
            "modifiers": modifiers,
        }
        self.call("Input.dispatchKeyEvent", type="keyDown", text=char, **key)
        self.call("Input.dispatchKeyEvent", type="keyUp", **key)


def main(argv: list[str]) -> int:
    devtools, page_url, key_file, screenshot, *agents = argv
    key = Path(key_file).read_text().strip()
    targets = json.load(urllib.request.urlopen(f"{devtools}/json/list", timeout=30))
    page = Page(next(t for t in targets if t["type"] == "page")["webSocketDebuggerUrl"])
    out: dict[str, Any] = {}
    try:
        page.call("Network.enable")
        page.call("Runtime.enable")
        page.call("Page.enable")
        page.call("Page.addScriptToEvaluateOnNewDocument", source=RECORDER)
        page.call(
            "Emulation.setDeviceMetricsOverride", width=1280, height=860, deviceScaleFactor=1, mobile=False
        )
        page.call("Page.navigate", url=page_url)
        page.wait(
            "location.pathname === '/login' && document.readyState === 'complete'", 30, "the sign-in page"
        )
        page.evaluate(
            f"document.getElementById('key').value = {json.dumps(key)}; "
            "document.querySelector('form').submit(); true"
        )
        page.wait("location.pathname === '/' && document.readyState === 'complete'", 30, "the console page")
        text = page.wait_text(agents, 90)
        out["agents_shown"] = [a for a in agents if a in text]
        page.wait("!!document.querySelector('.xterm-helper-textarea')", 10, "the terminal")
        page.evaluate("document.querySelector('.xterm-helper-textarea').focus(); true")
        page.press("T")
        page.wait_text(["Send TAKEOFF to ALL agents?"], 30)
        page.press("y")
        out["confirmed"] = True
        page.wait_text(["TAKEOFF → ALL (2)", "acked", "AIRBORNE"], 60)
        time.sleep(1.0)  # let the last frame reach the canvas before the picture
        shot = page.call("Page.captureScreenshot", format="png")
        Path(screenshot).write_bytes(base64.b64decode(shot["data"]))
        out["screenshot"] = screenshot
    except (TimeoutError, RuntimeError) as exc:
        out["error"] = str(exc)
        try:
            shot = page.call("Page.captureScreenshot", format="png")
            Path(screenshot).write_bytes(base64.b64decode(shot["data"]))
        except Exception:  # the picture of a failure is a bonus
            pass
    # drain late events for the request list
    page.ws.close()
    out["requests"] = page.requests
    out["js_errors"] = page.js_errors
    print(json.dumps(out), flush=True)
    return 0 if "error" not in out else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
