"""Run ``adaptfilt`` as a terminal would and stop it with a signal (tests of interrupts and resume).

:func:`start` puts the command in a process group of its own; :func:`stop` sends a signal (to the
group, as Ctrl-C does, or to the parent alone) and reports the seconds to exit, the status, stderr and
the worker processes still alive afterwards, found by pid in /proc (psutil is not a dependency).
"""
from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def adaptfilt(*args: str) -> list[str]:
    return [sys.executable, "-m", "adaptfilt", *args]


def descendants(pid: int) -> set[int]:
    """Every live process below ``pid`` (workers, the pool's resource tracker, Dask's workers)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                ppid = int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d))
    found, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            found.add(c)
            todo.append(c)
    return found


def in_group(pgid: int) -> set[int]:
    """Every live process of process group ``pgid``: :func:`start` makes the command a group leader, and its
    workers stay in its group even once orphaned (re-parented, so no longer its descendants)."""
    found = set()
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                state, _, pgrp = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[:3]
            except (OSError, ValueError):
                continue
            if int(pgrp) == pgid and state != "Z":
                found.add(int(d))
    return found


def alive(pid: int) -> bool:
    try:  # a zombie has exited: it only waits for a parent to collect its status
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


#: This checkout first, whatever is installed.
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def _default_sigint() -> None:
    # a shell starts background jobs (`pytest &`, nohup) with SIGINT ignored, and a child inherits that:
    # the command must get Ctrl-C as it does in a terminal
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
                            start_new_session=True, preexec_fn=_default_sigint)


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """Run to the end; fails the test unless it exits 0."""
    done = subprocess.run(args, cwd=cwd, capture_output=True, text=True, env=ENV, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def wait_for(what, timeout: float = 240.0, proc: subprocess.Popen | None = None, poll: float = 0.05) -> None:
    end = time.monotonic() + timeout
    while not what():
        if proc is not None and proc.poll() is not None:
            pytest.fail(f"exited ({proc.returncode}) before the moment to stop it: {proc.communicate()[1][-2000:]}")
        assert time.monotonic() < end, "timed out waiting"
        time.sleep(poll)


def _described(pids) -> list[str]:
    out = []
    for p in sorted(pids):
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
            cmd = Path(f"/proc/{p}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        out.append(f"{p} {state} {cmd[:120]}")
    return out


def stop(proc: subprocess.Popen, sig: int, group: bool) -> dict:
    """Send ``sig`` (to the process group, as Ctrl-C in a terminal does, or to the parent alone); return
    the seconds until the command exited and every process holding its stdout and stderr (its workers)
    had closed them, the status, stderr and the processes still alive 3 s later: the workers seen when
    the signal was sent, and any other process of the command's group (one started after it). When that
    took over 2 s, it prints when the command itself exited and what else of its group was alive then."""
    workers = descendants(proc.pid)
    seen: dict = {}

    def watch() -> None:  # when the command itself exits (a zombie, not yet collected), and who is left
        while "closed" not in seen:
            if "exited" not in seen and not alive(proc.pid):
                seen["others"] = _described(in_group(proc.pid) - {proc.pid})
                seen["exited"] = time.monotonic() - t0
            time.sleep(0.02)

    t0 = time.monotonic()
    (os.killpg if group else os.kill)(proc.pid, sig)
    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        print(f"not closed after 60 s; the command {'exited after %.2f s' % seen['exited'] if 'exited' in seen else 'runs'}"
              f"; its group: {_described(in_group(proc.pid))}")
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    finally:
        seen["closed"] = True
        watcher.join()
    seconds = time.monotonic() - t0
    end = time.monotonic() + 3
    while (any(alive(p) for p in workers) or in_group(proc.pid)) and time.monotonic() < end:
        time.sleep(0.05)
    left = sorted({p for p in workers if alive(p)} | in_group(proc.pid))
    for p in left:  # do not leave them to the rest of the suite
        os.kill(p, signal.SIGKILL)
    print(f"{signal.Signals(sig).name}: exit {proc.returncode} after {seconds:.2f} s; "
          f"{len(workers)} worker processes before, {len(left)} left")
    if seconds > 2:
        print(f"  the command exited after {seen.get('exited', seconds):.2f} s; then alive in its group: "
              f"{seen.get('others')}")
    return {"seconds": seconds, "rc": proc.returncode, "err": err, "workers": workers, "left": left}


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("adaptfilt: interrupted: "), err[-2000:]
    assert sum("adaptfilt:" in ln for ln in lines) == 1 and "Traceback" not in err, err[-2000:]
    return lines[-1]


def digests(paths) -> dict[str, str]:
    return {Path(p).name: hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in paths}


def lines(path: Path) -> int:
    return len(path.read_text().splitlines()) if path.exists() else 0
