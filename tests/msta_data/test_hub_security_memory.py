"""What anonymous bodies can cost a real ``msta-hub serve`` process (issue 41; docs/security.md).

The server runs as a subprocess with its default limits, so its peak resident memory (VmHWM in
/proc/<pid>/status) and CPU time are its own. Eight anonymous clients at a time send the
largest bodies it admits, in the shapes that cost most to parse: ``[{},{},...]`` JSON, YAML
cards of many small nodes, a card just under the node limit, an alias bomb and a merge-key
bomb. Every one is answered with a 4xx (or 200 for the legal card), and the process stays
far below 1 GB.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

MIB = 1 << 20
PARALLEL = 8


@pytest.fixture
def served(tmp_path):
    """(port, pid) of `msta-hub serve` with default limits."""
    port_file = tmp_path / "port"
    proc = subprocess.Popen([sys.executable, "-m", "msta.data.hub_cli", "serve", "--root", str(tmp_path / "hub"),
                             "--port-file", str(port_file)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not (port_file.exists() and port_file.read_text().strip()):
            assert proc.poll() is None and time.monotonic() < deadline, "server did not start"
            time.sleep(0.05)
        yield int(port_file.read_text()), proc.pid
    finally:
        proc.terminate()
        proc.communicate(timeout=20)


def _post(port: int, body: bytes) -> int:
    """POST /api/validate-yaml anonymously; the status (-1 when the server hung up first)."""
    head = b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
    with socket.create_connection(("127.0.0.1", port), timeout=120) as s:
        try:
            s.sendall(head + b"Content-Length: %d\r\n\r\n" % len(body) + body)
        except OSError:
            pass  # answered (413) and closed before the whole body was sent
        try:
            answer = s.recv(64)
        except OSError:
            return -1
    return int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/") else -1


def _card(front_matter: str) -> bytes:
    return json.dumps({"content": f"---\n{front_matter}\n---\n# card\n", "repoType": "model"}).encode()


def _bodies() -> dict[str, tuple[bytes, set[int]]]:
    """The largest anonymous bodies of each costly shape, and the answers they may get."""
    merge_bomb = "l0: &l0 {x: 1}\n" + "".join(f"l{i}: &l{i} {{<<: [*l{i - 1}, *l{i - 1}], k{i}: 1}}\n"
                                             for i in range(1, 60))
    laughs = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
        f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi", strict=True))
    return {
        "8 MiB of [{},...] (the authenticated cap)": (b"[" + b"{}," * ((8 * MIB - 4) // 3) + b"{}]", {413, -1}),
        "2 MiB of [{},...] (the anonymous cap)": (b"[" + b"{}," * ((2 * MIB - 4) // 3) + b"{}]", {400}),
        "1 MiB card of '- {}' lines": (_card("- {}\n" * (MIB // 5 - 10)), {400}),
        "card of 99,000 nodes": (_card("a: [" + "1," * 99_000 + "1]"), {200}),
        "merge-key bomb": (_card(merge_bomb), {400}),
        "alias bomb": (_card(laughs), {400}),
    }


def _peak_rss_mib(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    line = next(ln for ln in status.splitlines() if ln.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_eight_parallel_maximal_anonymous_bodies_stay_far_below_1_gb(served):
    port, pid = served
    idle_mib, costs = _peak_rss_mib(pid), {}
    with ThreadPoolExecutor(PARALLEL) as pool:
        for name, (body, allowed) in _bodies().items():
            cpu = _cpu_s(pid)
            statuses = list(pool.map(_post, [port] * PARALLEL, [body] * PARALLEL))
            costs[name] = (_cpu_s(pid) - cpu) / PARALLEL
            assert set(statuses) <= allowed, (name, statuses)
    peak = _peak_rss_mib(pid)
    print(f"server VmHWM {peak:.0f} MiB (idle {idle_mib:.0f}); CPU s per request: "
          + ", ".join(f"{k}: {v:.2f}" for k, v in costs.items()))
    assert peak < 512, (peak, costs)
    assert max(costs.values()) < 2.0, costs  # was 3.4 s for a 1 MiB card (CPU time, not wall time)
