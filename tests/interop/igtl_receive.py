#!/usr/bin/env python3
"""An independent OpenIGTLink receiver for the tests: pyigtl (PyPI, MIT) parses every header, checks every CRC
and decodes every message type it knows (TRANSFORM, STRING, POINT) with its own classes, metadata included.
pyigtl 0.3.4 cannot decode POLYDATA (not registered, and its reader is unfinished), so for POLYDATA its header
and metadata parsing is used and the content is read here from the protocol's table (ten uint32 counts, the
points as float32 triples, then the cell arrays, all big-endian).

  igtl_receive.py --connect HOST:PORT --out messages.json [--timeout S]   a live server, until it closes
  igtl_receive.py --file messages.bin --out messages.json                 messages written back to back

Writes one JSON object per message in the order received: type, device, timestamp, metadata, and the content
(matrix | text | points, colours | polydata). Exits non-zero on a CRC mismatch or a malformed message.
"""
import argparse
import json
import socket
import struct
import sys
import time

import pyigtl
from pyigtl.messages import CRC64, MessageBase


def read_exactly(read, n):
    out = b""
    while len(out) < n:
        chunk = read(n - len(out))
        if not chunk:
            return None if not out else out
        out += chunk
    return out


def polydata(content):
    counts = struct.unpack(">10I", content[:40])
    n_points, n_vertices, size_vertices, n_lines, size_lines, n_polygons, size_polygons = counts[:7]
    n_strips, size_strips, n_attributes = counts[7:]
    at = 40
    points = struct.unpack(f">{3 * n_points}f", content[at:at + 12 * n_points])
    at += 12 * n_points

    def cells(size):
        nonlocal at
        values = list(struct.unpack(f">{size // 4}I", content[at:at + size]))
        at += size
        return values

    vertices, lines = cells(size_vertices), cells(size_lines)
    polygons, strips = cells(size_polygons), cells(size_strips)
    if at != len(content) or n_attributes != 0:
        raise ValueError(f"POLYDATA: {len(content) - at} bytes left over, {n_attributes} attributes")
    return {
        "points": [points[i:i + 3] for i in range(0, len(points), 3)],
        "n_vertices": n_vertices, "vertices": vertices, "n_lines": n_lines, "lines": lines,
        "n_polygons": n_polygons, "polygons": polygons, "n_strips": n_strips, "strips": strips,
    }


def decode(header, body):
    fields = MessageBase.parse_header(header)
    crc = struct.unpack(">Q", header[50:58])[0]
    if CRC64(body) != crc:
        raise ValueError(f"{fields['message_type']} {fields['device_name']}: CRC mismatch")
    kind = fields["message_type"]
    message = MessageBase.create_message(kind)
    generic = message is None
    if generic:
        message = MessageBase()
    message.unpack(fields, body)
    out = {"type": kind, "device": message.device_name, "timestamp": message.timestamp, "bytes": len(header) + len(body),
           "header_version": message.header_version, "message_id": message.message_id,
           "metadata": dict(message.metadata)}
    if kind == "TRANSFORM":
        out["matrix"] = [[float(v) for v in row] for row in message.matrix]
    elif kind == "STRING":
        out["text"] = message.string
    elif kind == "POINT":
        out["points"] = [list(map(float, p)) for p in message.positions]
        out["rgba"] = [list(c) for c in message.rgba_colors]
        out["groups"] = list(message.groups)
    elif kind == "POLYDATA":
        extended, meta_header, meta_body = struct.unpack(">HHI", body[:8])
        end = len(body) - (meta_header + meta_body)
        out["polydata"] = polydata(body[extended:end])
    else:
        raise ValueError(f"unexpected message type {kind}")
    return out


def receive(read):
    messages = []
    while True:
        header = read_exactly(read, MessageBase.IGTL_HEADER_SIZE)
        if header is None:
            return messages
        if len(header) < MessageBase.IGTL_HEADER_SIZE:
            raise ValueError("a message cut in its header")
        size = MessageBase.parse_header(header)["body_size"]
        body = read_exactly(read, size) if size else b""
        if body is None or len(body) != size:
            raise ValueError("a message cut in its body")
        messages.append(decode(header, body))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect")
    parser.add_argument("--file")
    parser.add_argument("--out", required=True)
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args()
    if args.file:
        with open(args.file, "rb") as f:
            messages = receive(f.read)
    else:
        host, port = args.connect.rsplit(":", 1)
        # Imports done (pyigtl and numpy take a while to load on a busy machine): the caller may start the server.
        print("ready", flush=True)
        deadline = time.time() + args.timeout
        while True:
            try:
                conn = socket.create_connection((host, int(port)), timeout=1.0)
                break
            except OSError:
                if time.time() > deadline:
                    sys.exit(f"igtl_receive: nothing listens on {args.connect}")
                time.sleep(0.01)
        print("connected", flush=True)
        conn.settimeout(args.timeout)
        messages = receive(conn.recv)
        conn.close()
    with open(args.out, "w") as f:
        json.dump({"pyigtl": pyigtl.__version__ if hasattr(pyigtl, "__version__") else "?", "messages": messages}, f)
    print(f"igtl_receive: {len(messages)} messages", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
