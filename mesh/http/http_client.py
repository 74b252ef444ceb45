"""The WoT HTTP binding's client side: performs the http(s) forms of any TD (twinmesh's adapter, node-wot's
servient, the real lab) for `mesh.wot.consumed`.

Methods follow the form's `htv:methodName`, else the HTTP binding's defaults per op. Observations
and events use SSE forms (`subprotocol: sse`), and long-poll forms too for a client made with
`longpoll=True` (the bridge: the real lab's sensors offer only those). Error answers become
`Problem`s: problem+json as it came, anything else by its status code; a server that cannot be
reached is 503 (Unavailable), one that answers nothing usable 502.
"""
from __future__ import annotations

import json
import socket
import threading
from typing import Any

import httpx
import msgspec

from mesh.http.credentials import parse_auth as parse_credentials
from mesh.wot.consumed import NOTHING, Callback
from mesh.wot.invocation import ActionStatus
from mesh.wot.problem import UNREACHABLE, BadGateway, Problem, TimedOut, Unavailable
from mesh.wot.thing_description import Form

DEFAULT_METHODS = {"readproperty": "GET", "writeproperty": "PUT", "invokeaction": "POST",
                   "readallproperties": "GET", "readmultipleproperties": "GET", "writeallproperties": "PUT",
                   "writemultipleproperties": "PUT", "queryaction": "GET", "cancelaction": "DELETE",
                   "queryallactions": "GET", "observeproperty": "GET", "subscribeevent": "GET"}
PROBLEM = "application/problem+json"


def parse_auth(auth: str | None) -> httpx.Auth | None:
    """`bearer:TOKEN` or `basic:USER:PASS` (as `twinmesh up --auth` takes it) as an httpx auth."""
    credentials = parse_credentials(auth)
    if credentials is None:
        return None
    if credentials.scheme == "basic":
        user, _, password = credentials.secret.partition(":")
        return httpx.BasicAuth(user, password)
    return _Bearer(credentials.secret)


class _Bearer(httpx.Auth):
    def __init__(self, token: str):
        self.token = token

    def auth_flow(self, request: httpx.Request):
        request.headers["Authorization"] = f"Bearer {self.token}"
        yield request


def problem_of(r: httpx.Response) -> Problem:
    if r.headers.get("content-type", "").startswith(PROBLEM):
        return Problem.from_json(r.content)
    return Problem(f"{r.request.method} {r.request.url}: HTTP {r.status_code} {r.text[:200]}", status=r.status_code)


class HttpClient:
    """A `mesh.wot.consumed.ProtocolClient` over httpx, with one connection pool for every Thing."""

    schemes: tuple[str, ...] = ("http", "https")

    def __init__(self, auth: str | httpx.Auth | None = None, timeout: float = 10.0, action_timeout: float = 300.0,
                 verify: bool | str = True, longpoll: bool = False):
        """`verify`: check server certificates (True), against a CA file (its path), or not at all (False:
        say so loudly where you offer it). `longpoll`: also observe through long-poll forms."""
        self.http = httpx.Client(auth=parse_auth(auth) if isinstance(auth, str) or auth is None else auth,
                                 timeout=httpx.Timeout(timeout), headers={"Accept": "application/json"},
                                 verify=verify)
        self.action_timeout = action_timeout
        self.longpoll = longpoll

    def accepts(self, form: Form, op: str) -> bool:
        if op in ("observeproperty", "subscribeevent"):
            return form.subprotocol == "sse" or self.longpoll and form.subprotocol == "longpoll"
        return form.subprotocol is None

    def _send(self, form: Form, op: str, href: str | None = None, body: Any = NOTHING, timeout: float | None = None,
              **kwargs: Any) -> httpx.Response:
        method = form.method or DEFAULT_METHODS[op]
        if body is not NOTHING:
            kwargs["content"] = json.dumps(body).encode()
            kwargs["headers"] = {"Content-Type": form.contentType or "application/json"}
        try:
            r = self.http.request(method, href or form.href, timeout=timeout or httpx.USE_CLIENT_DEFAULT, **kwargs)
        except httpx.ConnectTimeout as e:
            raise Unavailable(f"{method} {href or form.href}: cannot connect ({e or 'timed out'})",
                              reason=UNREACHABLE) from None
        except httpx.TimeoutException as e:
            raise TimedOut(f"{method} {href or form.href}: no answer in time ({e})", reason=UNREACHABLE) from None
        except httpx.ConnectError as e:
            if "CERTIFICATE_VERIFY_FAILED" in str(e):
                raise BadGateway(f"{method} {href or form.href}: its TLS certificate is not trusted ({e})",
                                 reason="tls-untrusted") from None
            raise Unavailable(f"{method} {href or form.href}: cannot connect ({e})", reason=UNREACHABLE) from None
        except httpx.HTTPError as e:
            raise BadGateway(f"{method} {href or form.href}: {e}") from None
        if r.status_code >= 400:
            raise problem_of(r)
        return r

    @staticmethod
    def _json(r: httpx.Response) -> Any:
        if not r.content:
            return None
        try:
            return r.json()
        except ValueError:
            raise BadGateway(f"{r.request.url} answered no JSON: {r.text[:100]!r}") from None

    def fetch_td(self, url: str) -> dict[str, Any]:
        td = self._json(self._send(Form(href=url), "readproperty", headers={"Accept": "application/td+json"}))
        if not isinstance(td, dict):
            raise BadGateway(f"{url} answered no TD")
        return td

    def read(self, form: Form) -> Any:
        return self._json(self._send(form, "readproperty"))

    def write(self, form: Form, value: Any) -> None:
        self._send(form, "writeproperty", body=value)

    def invoke(self, form: Form, input: Any) -> Any:
        return self._json(self._send(form, "invokeaction", body=input, timeout=self.action_timeout))

    def invoke_async(self, form: Form, input: Any) -> ActionStatus:
        r = self._send(form, "invokeaction", body=input)
        status = _status(self._json(r))
        location = r.headers.get("location")
        return status if status.href or not location else _replace_href(status, str(r.url.join(location)))

    def query_action(self, href: str) -> ActionStatus:
        return _status(self._json(self._send(Form(href=href), "queryaction")))

    def cancel_action(self, href: str) -> ActionStatus | None:
        r = self._send(Form(href=href), "cancelaction")
        return _status(self._json(r)) if r.status_code != 204 and r.content else None

    def read_multiple(self, form: Form, names: list[str]) -> dict[str, Any]:
        values = self._json(self._send(form, "readmultipleproperties", params={"names": ",".join(names)}))
        if not isinstance(values, dict):
            raise BadGateway(f"{form.href} answered no property map")
        return values  # a server that ignores `names` answers all: the caller keeps those it asked for

    def query_all_actions(self, form: Form) -> dict[str, list[ActionStatus]]:
        found = self._json(self._send(form, "queryallactions")) or {}
        return {name: [_status(s) for s in statuses] for name, statuses in found.items()}

    def observe(self, form: Form, callback: Callback) -> "SseSubscription | LongPollSubscription":
        if form.subprotocol == "longpoll":
            return LongPollSubscription(self.http, form.href, callback)
        return SseSubscription(self.http, form.href, callback)

    def close(self) -> None:
        self.http.close()


def _status(data: Any) -> ActionStatus:
    try:
        return msgspec.convert(data, ActionStatus)
    except msgspec.ValidationError as e:
        raise BadGateway(f"no action status: {e}") from None


def _replace_href(status: ActionStatus, href: str) -> ActionStatus:
    return msgspec.structs.replace(status, href=href)


class SseSubscription:
    """One SSE stream read by a thread; registered (the server sent its headers) once the constructor
    returns. Each `data:` event's JSON goes to the callback, on that thread; a broken stream is reported
    to the callback as a `Problem` (502), once."""

    def __init__(self, http: httpx.Client, url: str, callback: Callback, timeout: float = 10.0):
        self.url, self._callback = url, callback
        self._opened = threading.Event()
        self._stopping = False
        self._response: httpx.Response | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._read, args=(http,), name="sse", daemon=True)
        self._thread.start()
        if not self._opened.wait(timeout):
            self.stop()
            raise TimedOut(f"{url}: the event stream did not open within {timeout:g} s")
        if self._error is not None:
            raise self._error

    def _read(self, http: httpx.Client) -> None:
        try:
            with http.stream("GET", self.url, headers={"Accept": "text/event-stream"},
                             timeout=httpx.Timeout(10.0, read=None)) as r:
                if r.status_code != 200:
                    r.read()
                    self._error = problem_of(r)
                    return
                self._response = r
                self._opened.set()
                data: list[str] = []
                for line in r.iter_lines():
                    if line.startswith("data:"):
                        data.append(line[5:].removeprefix(" "))
                    elif not line and data:
                        if not self._stopping:
                            self._callback(json.loads("\n".join(data)))
                        data = []
        except Exception as e:
            if not self._stopping:
                if not self._opened.is_set():
                    self._error = e
                else:
                    self._callback(BadGateway(f"the event stream {self.url} broke: {e}"))
        finally:
            self._opened.set()

    def stop(self) -> None:
        """Shut the socket down so that the reading thread wakes up, and wait for it."""
        self._stopping = True
        _wake_and_join(self._response, self._thread)


class LongPollSubscription:
    """A long-poll observation (node-wot's `subprotocol: longpoll`): one GET after the other, each answered
    with the next value, read by a thread. Registered once the constructor returns (the first GET is
    sent; a long-poll server has no other sign of it). A failed GET is reported to the callback as a
    `Problem`, once, and ends the subscription, as a broken SSE stream does."""

    def __init__(self, http: httpx.Client, url: str, callback: Callback, timeout: float = 10.0):
        self.url, self._callback = url, callback
        self._stopping = False
        self._response: httpx.Response | None = None
        self._sent = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(http, timeout), name="longpoll", daemon=True)
        self._thread.start()
        self._sent.wait(timeout)

    def _read(self, http: httpx.Client, timeout: float) -> None:
        try:
            while not self._stopping:
                with http.stream("GET", self.url, timeout=httpx.Timeout(timeout, read=None)) as r:
                    self._response = r
                    self._sent.set()
                    body = r.read()
                    if self._stopping:
                        return
                    if r.status_code >= 400:
                        raise problem_of(r)
                    if body:
                        self._callback(json.loads(body))
        except Exception as e:
            if not self._stopping:
                self._callback(e if isinstance(e, Problem) else BadGateway(f"the long poll {self.url} broke: {e}"))
        finally:
            self._sent.set()

    def stop(self) -> None:
        self._stopping = True
        _wake_and_join(self._response, self._thread)


def _wake_and_join(response: httpx.Response | None, thread: threading.Thread) -> None:
    """Shut a streaming response's socket down so that the thread reading it wakes up; wait for it."""
    stream = response.extensions.get("network_stream") if response is not None else None
    sock = stream.get_extra_info("socket") if stream is not None else None
    if sock is not None:
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
    if threading.current_thread() is not thread:
        thread.join(timeout=5)
