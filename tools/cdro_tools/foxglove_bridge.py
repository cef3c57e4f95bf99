"""cdro-foxglove: the service's live stream in Foxglove, over the Foxglove WebSocket protocol.

Follows one source: the live map's server-sent events (--sse, which also carry the links), the
JSON Lines (--jsonl FILE, followed as it grows, or - for stdin), or MQTT (--mqtt, the retained
topics give the state at once); serves ws://HOST:PORT (127.0.0.1:8765 by default) for Foxglove
("Open connection" -> Foxglove WebSocket). Topics (docs/outputs.md, "Foxglove and MCAP"):
/cdro/nodes, /cdro/links (SceneUpdate), /cdro/robot/pose (PoseInFrame), /cdro/robot/path
(PosesInFrame), /cdro/robot/scene (SceneUpdate), /tf (FrameTransforms: map -> odom ->
base_link), /cdro/health (JSON). The whole state is sent again every --republish-s, so a viewer
that connects later sees the map at once. Bad input is reported, counted and skipped.

examples:
  cdro-foxglove --sse http://127.0.0.1:8080/
  cdro-hostd --config config/cdro-hostd.example.yaml | cdro-foxglove --jsonl -
  cdro-foxglove --jsonl /var/lib/cdro/estimates.jsonl --port 8766
  cdro-foxglove --mqtt mqtt://127.0.0.1:1883 --mqtt-prefix cdro
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
import urllib.parse

import foxglove

from .export.recorder import FoxgloveChannels
from .export.stream import MapState, Tally, follow_sse, parse_jsonl_line, seconds_to_ns, unix_time_s
from .cli import entry_point

PROG = "cdro-foxglove"


def log(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr, flush=True)


def now_ns(obj: dict | None = None) -> int:
    """The message time: the stream's t_unix_s when it has one, else the time it arrived."""
    t_unix = unix_time_s(obj)
    return seconds_to_ns(t_unix) if t_unix is not None else time.time_ns()


class Bridge:
    """The map state and its Foxglove channels; every method may be called from any thread."""

    def __init__(self, tally: Tally):
        self.state = MapState()
        self.channels = FoxgloveChannels()
        self.lock = threading.Lock()
        self.tally = tally
        self.updates = 0

    def line(self, obj: dict, where: str) -> None:
        """One checked JSON Lines object."""
        t_ns = now_ns(obj)
        with self.lock:
            kind = self.state.apply(obj)
            try:
                if kind == "node":
                    self.channels.nodes(self.state, t_ns, {obj["id"]})
                elif kind == "robot":
                    self.channels.robot(self.state, t_ns)
                else:
                    self.channels.health(self.state, t_ns)
            except (ValueError, TypeError, OverflowError) as error:
                # A value the checks let through that no message can hold: this line only.
                self.tally.drop(where, f"cannot be sent ({error})")
            self.updates += 1

    def map_event(self, event: dict, where: str) -> None:
        """One live map event: the whole map."""
        with self.lock:
            self.state.apply_map(event, self.tally, where)
            t_ns = now_ns(event)
            try:
                self.channels.nodes(self.state, t_ns)
                self.channels.robot(self.state, t_ns)
                self.channels.health(self.state, t_ns)
            except (ValueError, TypeError, OverflowError) as error:
                self.tally.drop(where, f"cannot be sent ({error})")
            self.updates += 1

    def republish(self) -> None:
        """Everything again, for viewers that connected since."""
        with self.lock:
            if not self.updates:
                return
            self.channels.nodes(self.state, now_ns())
            # The robot keeps its own time when the stream gave one.
            self.channels.robot(self.state, now_ns(self.state.robot), repeat=True)


def follow_file(path: str, stop: threading.Event, follow: bool):
    """The lines of a file, then (follow) the lines appended to it, as `tail -F` does: a file
    that was truncated or replaced is read again from its start."""
    while not stop.is_set():
        try:
            handle = open(path, encoding="utf-8", errors="replace")
        except OSError as error:
            if not follow:
                raise
            log(f"{path}: {error}; waiting for it")
            stop.wait(0.5)
            continue
        with handle:
            identity = os.fstat(handle.fileno()).st_ino
            partial = ""
            while not stop.is_set():
                text = handle.readline()
                if text:
                    partial += text
                    if partial.endswith("\n"):
                        yield partial
                        partial = ""
                    continue
                if not follow:
                    if partial:
                        yield partial
                    return
                try:
                    status = os.stat(path)
                except OSError:
                    status = None
                if status is None or status.st_ino != identity or status.st_size < handle.tell():
                    log(f"{path}: replaced or truncated; reading it from the start")
                    break
                stop.wait(0.1)


def run_jsonl(bridge: Bridge, source: str, follow: bool, stop: threading.Event, tally: Tally) -> None:
    lines = sys.stdin if source == "-" else follow_file(source, stop, follow)
    name = "stdin" if source == "-" else source
    for number, text in enumerate(lines, start=1):
        where = f"{name}:{number}"
        obj = parse_jsonl_line(text, where, tally)
        if obj is not None:
            bridge.line(obj, where)
        if stop.is_set():
            return


def run_mqtt(bridge: Bridge, url: str, prefix: str, qos: int, stop: threading.Event, tally: Tally) -> None:
    import paho.mqtt.client as mqtt  # only this source needs it

    parsed = urllib.parse.urlparse(url)
    if parsed.scheme != "mqtt" or not parsed.hostname:
        raise ValueError(f"--mqtt {url}: expected mqtt://host[:port]")
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"{PROG}-{os.getpid()}")
    topics = [f"{prefix}/nodes/+", f"{prefix}/robot", f"{prefix}/health"]

    def on_connect(client, userdata, flags, reason_code, properties):
        log(f"connected to {url}: {reason_code}; subscribing to {', '.join(topics)}")
        for topic in topics:
            client.subscribe(topic, qos=qos)

    def on_message(client, userdata, message):
        where = f"mqtt {message.topic}"
        obj = parse_jsonl_line(message.payload.decode("utf-8", errors="replace"), where, tally)
        if obj is not None:
            bridge.line(obj, where)

    client.on_connect = on_connect
    client.on_message = on_message
    client.reconnect_delay_set(min_delay=1, max_delay=30)
    client.connect_async(parsed.hostname, parsed.port or 1883)
    client.loop_start()
    try:
        stop.wait()
    finally:
        client.loop_stop()
        client.disconnect()


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--sse", metavar="URL", help="the live map (http://127.0.0.1:8080/); links come only from here")
    source.add_argument("--jsonl", metavar="FILE", help="cdro-hostd's JSON Lines: a file (followed as it grows) or -")
    source.add_argument("--mqtt", metavar="URL", help="mqtt://host[:port] of the broker cdro-hostd publishes to")
    parser.add_argument("--mqtt-prefix", default="cdro", help="mqtt.topic_prefix of the service (default cdro)")
    parser.add_argument("--mqtt-qos", type=int, choices=(0, 1, 2), default=1,
                        help="subscription QoS (default 1; a message arrives at the lower of this and "
                             "the service's mqtt.qos; QoS 0 is at most once)")
    parser.add_argument("--no-follow", action="store_true", help="--jsonl FILE: read it once, do not wait for more")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8765,
                        help="TCP port of the WebSocket server (default 8765; 0 = any)")
    parser.add_argument("--republish-s", type=float, default=1.0,
                        help="s between full repeats of the state for late viewers (default 1; 0 = never)")
    args = parser.parse_args(argv)
    if not 0 <= args.port <= 65535:
        parser.error("--port must be 0..65535")
    if args.sse and not args.sse.startswith(("http://", "https://")):
        parser.error("--sse needs an http:// URL")

    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    try:
        server = foxglove.start_server(name=PROG, host=args.host, port=args.port)
    except Exception as error:  # the SDK raises its own error types for a port in use or a bad address
        log(f"cannot serve on {args.host}:{args.port}: {error}")
        return 2
    log(f"serving ws://{args.host}:{server.port} (Foxglove: Open connection -> Foxglove WebSocket)")
    tally = Tally(args.sse or args.jsonl or args.mqtt)
    bridge = Bridge(tally)

    def republish():
        while not stop.wait(args.republish_s):
            bridge.republish()

    if args.republish_s > 0:
        threading.Thread(target=republish, daemon=True, name="republish").start()
    failure: list[str] = []

    def read():
        # On its own thread: a blocking read (an idle event stream, stdin) must not keep a signal
        # from stopping the server.
        try:
            if args.sse:
                for number, event in enumerate(follow_sse(args.sse, tally, stop.is_set, log), start=1):
                    bridge.map_event(event, f"event {number}")
            elif args.jsonl:
                run_jsonl(bridge, args.jsonl, not args.no_follow, stop, tally)
            else:
                run_mqtt(bridge, args.mqtt, args.mqtt_prefix, args.mqtt_qos, stop, tally)
            if not stop.is_set():
                log("the input ended; still serving the last state until SIGINT/SIGTERM")
        except (OSError, ValueError) as error:
            failure.append(str(error))
            stop.set()

    threading.Thread(target=read, daemon=True, name="read").start()
    while not stop.wait(0.5):
        pass
    server.stop()
    for message in failure:
        log(message)
    log(tally.summary())
    return 2 if failure else 0


if __name__ == "__main__":
    raise SystemExit(main())
