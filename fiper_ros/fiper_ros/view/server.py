"""The Foxglove WebSocket server of the live view (``foxglove-sdk``), without rclpy.

One channel per topic, advertised to every client that connects (protocol ``foxglove.websocket.v1``, also
``foxglove.sdk.v1``); a client subscribes to the channels it shows. JSON channels carry the messages as
:mod:`.translate` makes them, with their JSON Schema; image channels carry ``foxglove.RawImage``.

A slow client never holds anything up: the SDK keeps at most ``backlog`` messages per client and drops the
oldest when that queue is full (the SDK's ``message_backlog_size``), so a client that reads slowly, or not at
all, loses messages and the others and the node go on. A message is only translated when a client subscribes
to its channel (:meth:`ViewServer.wanted`): with no client the view costs the suite nothing but the DDS copy.
"""
from __future__ import annotations

import errno
import socket
import threading
from collections import Counter
from typing import Any

import foxglove
from foxglove.channels import RawImageChannel
from foxglove.websocket import ChannelView, Client, ServerListener

from fiper_ros.errors import FiperError
from fiper_ros.view.translate import json_schema, raw_image, to_json

#: How Foxglove is pointed at the server, for the messages that print its address.
HOW_TO_OPEN = "in Foxglove: Open connection > Foxglove WebSocket"
#: Where the view listens unless told otherwise: this machine only, Foxglove's default port.
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: Messages queued per client before the oldest is dropped.
DEFAULT_BACKLOG = 256


class ViewError(FiperError):
    """The server cannot run (the message says why, on one line)."""


def address(host: str, port: int) -> str:
    """The WebSocket URL of a server on ``host``:``port``."""
    return f"ws://{host}:{port}"


def port_problem(host: str, port: int) -> str:
    """Why ``port`` on ``host`` cannot be served on now (``""``: it can), tried as a server binds it
    (``SO_REUSEADDR``: a port whose last connection is still closing is free). Port 0 means any free port."""
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except OSError as error:
        if error.errno == errno.EADDRINUSE:
            return f"port {port} on {host} is taken (another live view, or a Foxglove bridge?)"
        return f"cannot serve on {host}:{port}: {error.strerror or error}"
    return ""


class _Subscriptions(ServerListener):
    """Which client is subscribed to which channel (the SDK calls this from its own threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_client: dict[int, set[int]] = {}

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._by_client.setdefault(client.id, set()).add(channel.id)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            channels = self._by_client.get(client.id, set())
            channels.discard(channel.id)
            if not channels:
                self._by_client.pop(client.id, None)

    def counts(self) -> tuple[int, int]:
        """(clients with a subscription, subscriptions)."""
        with self._lock:
            return len(self._by_client), sum(len(c) for c in self._by_client.values())


class ViewServer:
    """A Foxglove WebSocket server on ``host``:``port`` (0: any free port) with channels added by topic.

    Raises:
        ViewError: The port is taken or cannot be bound.
    """

    def __init__(self, name: str, host: str, port: int, backlog: int) -> None:
        self.host = host
        self._context = foxglove.Context()
        self._listener = _Subscriptions()
        self._json: dict[str, foxglove.Channel] = {}
        self._images: dict[str, RawImageChannel] = {}
        #: Messages sent per topic (to at least one client).
        self.sent: Counter[str] = Counter()
        problem = port_problem(host, port)
        if problem:
            raise ViewError(problem)
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 server_listener=self._listener, message_backlog_size=backlog)
        except RuntimeError as error:  # taken meanwhile, or not an address of this machine
            raise ViewError(f"cannot serve on {host}:{port}: {error}") from error

    @property
    def port(self) -> int:
        """The port the server listens on (the one chosen, for port 0)."""
        return self._server.port

    @property
    def url(self) -> str:
        """The address to open in Foxglove."""
        return address(self.host, self.port)

    def add_json(self, topic: str, cls: type) -> None:
        """A JSON channel on ``topic`` for messages of class ``cls`` (schema: :func:`.translate.json_schema`)."""
        self._json[topic] = foxglove.Channel(topic, schema=json_schema(cls), context=self._context)

    def add_image(self, topic: str) -> None:
        """A ``foxglove.RawImage`` channel on ``topic`` for ``sensor_msgs/Image`` messages."""
        self._images[topic] = RawImageChannel(topic, context=self._context)

    def topics(self) -> list[str]:
        """Every topic served, sorted."""
        return sorted([*self._json, *self._images])

    def wanted(self, topic: str) -> bool:
        """Whether a client is subscribed to ``topic`` (only then is its message worth translating)."""
        channel = self._json.get(topic) or self._images.get(topic)
        return channel is not None and channel.has_sinks()

    def send(self, topic: str, msg: Any) -> None:
        """Translate ``msg`` and send it to the clients subscribed to ``topic``."""
        if topic in self._json:
            self._json[topic].log(to_json(msg))
        else:
            self._images[topic].log(raw_image(msg))
        self.sent[topic] += 1

    def clients(self) -> tuple[int, int]:
        """(clients with a subscription, their subscriptions)."""
        return self._listener.counts()

    def stop(self) -> None:
        """Stop serving (clients are disconnected)."""
        self._server.stop()
