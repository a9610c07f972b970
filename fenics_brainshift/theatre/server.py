"""The OpenIGTLink server: one thread, one selector, every client its own session (its own
case: an update never mixes two clients' points unless the service is told to share one).

Each turn of the loop reads what every client sent, handles each message (session.py), then
makes the updates asked for, one per client however many messages asked (a 60 Hz tip stream
or a flood of `update` strings costs one update: the latest points win), then writes. Bad
traffic is dropped with one log line: a body that fails its CRC is skipped and the client
kept; a header that cannot be read (a wrong type, a body over its limit, garbage) closes that
client, as the stream cannot be found again after it. A client that does not read its answers
is closed once MAX_OUTBOX bytes wait for it. Recording (record.py) is written before the
answer goes out.
"""

from __future__ import annotations

import ipaddress
import selectors
import socket
import time
from collections.abc import Callable

from ..errors import InputError
from . import igtl
from .session import Session

MAX_OUTBOX = 256 << 20  # bytes waiting for a client that does not read
READ_CHUNK = 1 << 20
MAX_CLIENTS = 16
LOG_BURST, LOG_WINDOW = 20, 10.0  # lines about one client's messages, per seconds
IDLE_S = 30.0  # with every place taken, a client silent this long gives its place to a new one


class _Client:
    def __init__(self, sock: socket.socket, address, number: int, session: Session):
        self.sock, self.address, self.number, self.session = sock, address, number, session
        self.reader = igtl.Reader()
        self.outbox = bytearray()
        self.pending = False  # an update asked for
        self.received = 0  # messages, for the record
        self.window, self.said, self.quiet = time.monotonic(), 0, 0  # its log lines (Server._say)
        self.heard = time.monotonic()  # when it last sent anything
        self.closing = False  # it closed its side: answered what it asked, then closed
        self.answering = False  # an answer's messages are being queued
        self.registered = True


def printable(line: str) -> str:
    """A log line with control characters escaped (a label's newline forged lines of its own)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in line)


def _address(name: str, flag: str) -> str:
    try:
        return socket.gethostbyname(name)
    except (OSError, UnicodeError) as exc:
        raise InputError(f"{flag} {name!r}: not an IPv4 address or a name this machine resolves ({exc})") from None


def loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        return False


class Server:
    """serve(until) runs the loop until `until()` is true; the socket is bound on creation
    (port 0: any free port, then .port says which)."""

    def __init__(
        self,
        new_session: Callable[[], Session],
        host: str = "127.0.0.1",
        port: int = 18944,
        allow: list[str] | None = None,
        recorder=None,
        log: Callable[[str], None] = print,
    ):
        self.new_session, self.recorder = new_session, recorder
        self.log = lambda line: log(printable(line))  # (a client's labels and commands may hold any character)
        self.allow = None if not allow else {_address(a, "--allow") for a in allow}
        _address(host, "--host")
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((host, port))
        except OSError as exc:
            self.listener.close()
            raise InputError(
                f"--port {port} on {host}: {exc.strerror} (another server there? --port to choose)"
            ) from None
        self.listener.listen(8)
        self.listener.setblocking(False)
        self.port = self.listener.getsockname()[1]
        self.selector = selectors.DefaultSelector()
        self.selector.register(self.listener, selectors.EVENT_READ)
        self.clients: dict[int, _Client] = {}
        self._numbers = 0 if recorder is None else recorder.first_client - 1  # (numbers run on across starts)
        self.updates = 0

    def serve(self, until: Callable[[], bool] = lambda: False, tick: float = 0.05) -> None:
        try:
            while not until():
                self.step(tick)
        finally:
            self.close()

    def step(self, timeout: float) -> None:
        for key, events in self.selector.select(timeout):
            if key.fileobj is self.listener:
                self._accept()
                continue
            client = key.data
            if events & selectors.EVENT_READ and client.number in self.clients:
                self._read(client)
            if events & selectors.EVENT_WRITE and client.number in self.clients:
                self._write(client)
        for client in list(self.clients.values()):
            if client.pending:
                client.pending = False
                self._answer(client)

    def close(self) -> None:
        for client in list(self.clients.values()):
            self._drop(client, None)
        self.selector.close()
        self.listener.close()

    # -- the clients -------------------------------------------------------------------------

    def _accept(self) -> None:
        try:
            sock, address = self.listener.accept()
        except OSError:
            return
        if self.allow is not None and address[0] not in self.allow:
            self.log(f"refused {address[0]}:{address[1]}: not among --allow")
            sock.close()
            return
        if len(self.clients) >= MAX_CLIENTS:
            idle = min(self.clients.values(), key=lambda c: c.heard)
            if time.monotonic() - idle.heard < IDLE_S:
                self.log(f"refused {address[0]}:{address[1]}: {MAX_CLIENTS} clients already, none idle")
                sock.close()
                return
            self._drop(idle, f"silent {time.monotonic() - idle.heard:.0f} s, its place given to a new client")
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._numbers += 1
        client = _Client(sock, address, self._numbers, self.new_session())
        self.clients[client.number] = client
        self.selector.register(sock, selectors.EVENT_READ, client)
        self.log(f"client {client.number} connected from {address[0]}:{address[1]}")

    def _say(self, client: _Client, line: str) -> None:
        """A line about a client's message, at most LOG_BURST of them per LOG_WINDOW seconds (a
        flood's every message would be a line: a log no one can read, a pipe that fills)."""
        now = time.monotonic()
        if now - client.window > LOG_WINDOW:
            if client.quiet:
                self.log(f"client {client.number}: {client.quiet} more such lines not shown")
            client.window, client.said, client.quiet = now, 0, 0
        client.said += 1
        if client.said <= LOG_BURST:
            self.log(f"client {client.number}: {line}")
        else:
            client.quiet += 1

    def _drop(self, client: _Client, why: str | None) -> None:
        if client.quiet:
            self.log(f"client {client.number}: {client.quiet} more such lines not shown")
        if why:
            self.log(f"client {client.number}: {why}; closed")
        self.clients.pop(client.number, None)
        if client.registered:
            try:
                self.selector.unregister(client.sock)
            except (KeyError, ValueError):
                pass
            client.registered = False
        client.sock.close()

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._drop(client, f"receive failed ({exc.strerror})")
            return
        if not data:
            if client.reader.pending:
                self._drop(client, "disconnected mid-message")
            elif client.pending or client.outbox:  # (it closed its side only: its answer still goes out)
                client.closing = True
                self._events(client)
            else:
                self._drop(client, "disconnected")
            return
        client.heard = time.monotonic()
        try:
            messages = client.reader.feed(data)
        except igtl.ProtocolError as exc:
            self._drop(client, f"unreadable header ({exc})")
            return
        for header, body in messages:
            self._message(client, header, body)

    def _message(self, client: _Client, header: igtl.Header, body: bytes) -> None:
        client.received += 1
        arrived = time.time()
        if self.recorder is not None:
            self.recorder.received(client.number, header, body, arrived)
        try:
            igtl.check_body(header, body)
            message = igtl.decode(header, body)
        except igtl.ProtocolError as exc:
            self._say(client, f"{header.type} {header.device!r} dropped ({exc})")
            return
        try:
            reply = client.session.handle(message, arrived)
        except Exception as exc:  # a fault here must not stop the service for every client  # noqa: BLE001
            self._say(client, f"{header.type} {header.device!r} dropped: internal error {exc!r}")
            return
        if reply.log:
            self._say(client, f"{reply.log}")
        for data in reply.send:
            self._send(client, data)
        # (a refused list after a good one in the same turn: its error is the last word, not the
        # older list's answer)
        client.pending = (client.pending or reply.update) and not reply.refused

    def _answer(self, client: _Client) -> None:
        started = time.perf_counter()
        try:
            messages = client.session.answer()
        except Exception as exc:  # (as in _message: logged, that update not made, the service kept)  # noqa: BLE001
            self.log(f"client {client.number}: the update failed: internal error {exc!r}")
            return
        self.updates += 1
        if self.recorder is not None:  # (on disk before the answer goes out)
            self.recorder.answered(client.number, messages, time.perf_counter() - started)
        client.answering = True
        for data in messages:
            self._send(client, data)
        client.answering = False
        if client.number in self.clients and client.closing:
            self._events(client)

    def _send(self, client: _Client, data: bytes) -> None:
        if client.number not in self.clients:
            return
        client.outbox += data
        self._write(client)
        if len(client.outbox) > MAX_OUTBOX:
            self._drop(client, f"{len(client.outbox) >> 20} MB of answers not read")

    def _write(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.outbox) if client.outbox else 0
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError as exc:
            self._drop(client, f"send failed ({exc.strerror})")
            return
        del client.outbox[:sent]
        self._events(client)

    def _events(self, client: _Client) -> None:
        """Watch the client for what it can still do: read unless it closed its side, write
        while answers wait; a closed client with nothing left to answer is let go."""
        events = (0 if client.closing else selectors.EVENT_READ) | (selectors.EVENT_WRITE if client.outbox else 0)
        if events:
            if client.registered:
                self.selector.modify(client.sock, events, client)
            else:
                self.selector.register(client.sock, events, client)
                client.registered = True
        elif client.closing and not client.pending and not client.answering:
            self._drop(client, None)
        elif client.registered:
            self.selector.unregister(client.sock)
            client.registered = False
