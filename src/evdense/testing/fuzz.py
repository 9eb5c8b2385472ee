"""Fuzzing the recording readers: mutated files, one forked process per case, with limits.

:func:`make_seeds` writes one small valid recording per format with our own writers (and adds
the real files of the anchors folder when given); :func:`mutate` derives a seeded mutant of a seed
(bit flips, overwritten bytes and length-like fields, truncation, insertion, deletion,
duplication; for text, whole lines: blank runs, NaN, negative, huge and off-sensor values);
:func:`run_case` converts a mutant with :func:`evdense.io.ingest.ingest_recording` in a forked
child (so the readers are imported once) under an address-space limit and a time limit, and
classifies what happened:

- ``ok``: converted (then the output is read back through the checks of the canonical file);
- ``clean``: an :class:`~evdense.errors.InputError` whose message names the mutant;
- ``unnamed``: an ``InputError`` that does not name it;
- ``foreign``: any other exception (the message says which);
- ``crash``: the child died of a signal (segmentation fault, abort);
- ``timeout`` / ``memory``: over the time limit / out of memory (``MemoryError`` or killed);
- ``bigrss``: finished, but its peak resident memory passed ``rss_limit_mb``.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import time
import traceback
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OUTCOMES = ("ok", "clean", "unnamed", "foreign", "crash", "timeout", "memory", "bigrss")
BAD_OUTCOMES = ("unnamed", "foreign", "crash", "timeout", "memory", "bigrss")


@dataclass
class Seed:
    """A valid recording to mutate: ``path`` is a file, or a folder whose ``member`` is mutated."""

    name: str
    path: Path
    member: str | None = None
    text: bool = False


def _toy_events(n: int = 3000, w: int = 64, h: int = 48, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(1_000, 500_000, n)).astype(np.int64)
    x = rng.integers(0, w, n)
    y = rng.integers(0, h, n)
    p = np.where(rng.random(n) < 0.5, 1, -1)
    return t, x, y, p, w, h


# Over 80 lines on purpose: a list of one small recording per format, each a few lines.
def make_seeds(folder: str | Path, anchors: str | Path | None = None) -> list[Seed]:
    """Write one small recording per format into ``folder`` (plus the anchors' real files)."""
    from evdense.events.container import Events, write_events
    from evdense.testing.recordings import (
        write_aedat4,
        write_dat,
        write_e2vid_h5,
        write_evt2,
        write_evt3,
        write_npy,
        write_npz,
        write_rosbag1,
        write_rpg_text,
    )

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    t, x, y, p, w, h = _toy_events()
    frame = (np.arange(w * h, dtype=np.uint8).reshape(h, w) * 3).astype(np.uint8)
    seeds = []
    write_rpg_text(d / "rpg", t, x, y, p)
    (d / "rpg" / "images").mkdir(exist_ok=True)
    import imageio.v3 as iio

    iio.imwrite(d / "rpg" / "images" / "f0.png", frame)
    (d / "rpg" / "images.txt").write_text("0.000500 images/f0.png\n")
    (d / "rpg" / "calib.txt").write_text("50 50 32 24 0 0 0 0 0\n")
    seeds.append(Seed("rpg_text", d / "rpg", "events.txt", text=True))
    seeds.append(Seed("rpg_images", d / "rpg", "images.txt", text=True))
    with zipfile.ZipFile(d / "rpg.zip", "w", zipfile.ZIP_DEFLATED) as z:
        z.write(d / "rpg" / "events.txt", "rpg/events.txt")
        z.write(d / "rpg" / "calib.txt", "rpg/calib.txt")
    seeds.append(Seed("rpg_zip", d / "rpg.zip"))
    write_e2vid_h5(d / "e2vid.h5", t, x, y, p, w, h, frames=[(600, frame)])
    seeds.append(Seed("e2vid_h5", d / "e2vid.h5"))
    write_events(d / "canonical.h5", Events(t, x.astype(np.uint16), y.astype(np.uint16),
                                            p.astype(np.int8)), w, h)  # fmt: skip
    seeds.append(Seed("evdense_h5", d / "canonical.h5"))
    write_aedat4(d / "rec.aedat4", t, x, y, p, w, h, frames=[(600, frame)], packet_events=500)
    seeds.append(Seed("aedat4", d / "rec.aedat4"))
    write_rosbag1(d / "rec.bag", t, x, y, p, w, h, events_per_message=500)
    seeds.append(Seed("rosbag1", d / "rec.bag"))
    write_evt2(d / "rec2.raw", t, x, y, p, w, h)
    seeds.append(Seed("evt2", d / "rec2.raw"))
    write_evt3(d / "rec3.raw", t, x, y, p, w, h)
    seeds.append(Seed("evt3", d / "rec3.raw"))
    write_dat(d / "rec.dat", t, x, y, p, w, h)
    seeds.append(Seed("dat", d / "rec.dat"))
    write_npz(d / "rec.npz", t, x, y, p)
    seeds.append(Seed("npz", d / "rec.npz"))
    write_npy(d / "rec.npy", t, x, y, p)
    seeds.append(Seed("npy", d / "rec.npy"))
    if anchors is not None and Path(anchors).is_dir():
        a = Path(anchors) / "data"
        real = [
            ("real_aedat4", a / "dvxplorer_sample.aedat4", None),
            ("real_evt2", a / "prophesee" / "evt2_sample.raw", None),
            ("real_evt3", a / "prophesee" / "evt3_sample.raw", None),
            ("real_rosbag1", a / "ros" / "event_camera_msgs_evt3.bag", None),
            ("real_rosbag2", a / "ros" / "event_camera_msgs_evt3_ros2", "test_events_2_0.mcap"),
        ]
        for name, src, member in real:
            if not src.exists():
                continue
            dst = d / ("real_" + src.name)
            if src.is_dir():
                shutil.copytree(src, dst, dirs_exist_ok=True)
                for f in dst.iterdir():
                    f.chmod(0o644)
            else:
                shutil.copyfile(src, dst)
            seeds.append(Seed(name, dst, member))
        ecd = a / "ecd_slider_depth" / "events.txt"
        if ecd.exists():  # the first 3000 lines of a real ECD text file
            (d / "real_ecd").mkdir(exist_ok=True)
            with open(ecd) as f:
                head = [next(f) for _ in range(3000)]
            (d / "real_ecd" / "events.txt").write_text("".join(head))
            shutil.copyfile(a / "ecd_slider_depth" / "calib.txt", d / "real_ecd" / "calib.txt")
            seeds.append(Seed("real_ecd_text", d / "real_ecd", "events.txt", text=True))
    return seeds


# ---------------------------------------------------------------------------------------------
# Mutations
# ---------------------------------------------------------------------------------------------

_INTERESTING = [b"\x00", b"\xff", b"\x7f", b"\x80", b"\xff\xff\xff\xff", b"\x00\x00\x00\x80",
                b"\xff\xff\xff\x7f", b"\xff" * 8, b"\x00\x00\x00\x00\x00\x00\xf0\x7f"]  # fmt: skip
_TEXT_VALUES = ["nan", "-1", "1e300", "99999999999", "-0.5", "18446744073709551616", "inf",
                "0x10", "", "1.5.3", "\xe9", "65536", "-32768"]  # fmt: skip


def mutate(data: bytes, rng: np.random.Generator, text: bool = False) -> bytes:
    """A seeded mutant of ``data`` (one to three mutations)."""
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        kinds = ["flip", "bytes", "truncate", "insert", "delete", "duplicate", "zero"]
        if text:
            kinds += ["line"] * 4 + ["blank"] * 2
        kind = str(rng.choice(kinds))
        n = len(out)
        if n == 0:
            out = bytearray(
                rng.integers(0, 256, int(rng.integers(1, 64))).astype(np.uint8).tobytes()
            )
            continue
        i = int(rng.integers(0, n))
        if kind == "flip":
            for _ in range(int(rng.integers(1, 9))):
                j = int(rng.integers(0, n))
                out[j] ^= 1 << int(rng.integers(0, 8))
        elif kind == "bytes":
            v = _INTERESTING[int(rng.integers(len(_INTERESTING)))]
            out[i : i + len(v)] = v
        elif kind == "truncate":
            del out[i:]
        elif kind == "insert":
            out[i:i] = rng.integers(0, 256, int(rng.integers(1, 256))).astype(np.uint8).tobytes()
        elif kind == "delete":
            del out[i : i + int(rng.integers(1, 512))]
        elif kind == "duplicate":
            j = int(rng.integers(i, min(n, i + 4096) + 1))
            out[i:i] = out[i:j]
        elif kind == "zero":
            out[i : i + int(rng.integers(1, 256))] = b"\x00" * min(n - i, int(rng.integers(1, 256)))
        elif kind == "blank":
            out[i:i] = (b"\n" if rng.random() < 0.7 else b"#\n") * int(rng.integers(1, 20000))
        else:  # replace one field of one line by a nasty value
            lines = bytes(out).split(b"\n")
            k = int(rng.integers(0, len(lines)))
            fields = lines[k].split(b" ")
            f = int(rng.integers(0, len(fields)))
            fields[f] = _TEXT_VALUES[int(rng.integers(len(_TEXT_VALUES)))].encode("utf-8")
            lines[k] = b" ".join(fields)
            out = bytearray(b"\n".join(lines))
    return bytes(out)


def write_mutant(seed: Seed, case_dir: Path, rng: np.random.Generator) -> Path:
    """Write a mutant of ``seed`` under ``case_dir``; returns the path to hand to the reader."""
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir(parents=True)
    if seed.path.is_dir():
        dst = case_dir / seed.path.name
        shutil.copytree(seed.path, dst)
        target = dst / str(seed.member)
        target.write_bytes(mutate(target.read_bytes(), rng, seed.text))
        return dst
    dst = case_dir / seed.path.name
    dst.write_bytes(mutate(seed.path.read_bytes(), rng, seed.text))
    return dst


# ---------------------------------------------------------------------------------------------
# One case in a forked child
# ---------------------------------------------------------------------------------------------


@dataclass
class CaseResult:
    outcome: str
    message: str
    seconds: float
    rss_mb: float


def _child(path: Path, out_dir: Path, mem_bytes: int, timeout_s: int, wfd: int) -> None:
    from evdense.errors import InputError
    from evdense.events.container import EventFile
    from evdense.io.ingest import ingest_recording

    resource.setrlimit(resource.RLIMIT_AS, (mem_bytes, mem_bytes))
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(timeout_s)
    try:
        out = out_dir / "events.h5"
        ingest_recording(path, out, conventional_dir=out_dir / "conv", gt_dir=out_dir / "gt")
        with EventFile(out) as f:
            for _ in f.iter_chunks(1 << 18):
                pass
        res = ("ok", "")
    except InputError as e:
        res = ("clean" if str(path) in str(e) else "unnamed", str(e)[:300])
    except MemoryError:
        res = ("memory", "MemoryError")
    except BaseException as e:  # noqa: BLE001 - classifying every failure is the point
        tb = traceback.extract_tb(e.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
        res = ("foreign", f"{type(e).__name__} at {where}: {str(e)[:200]}")
    os.write(wfd, json.dumps(res).encode())
    os._exit(0)


def run_case(path: Path, out_dir: Path, mem_limit_mb: int = 4096, timeout_s: int = 20,
             rss_limit_mb: int = 2048) -> CaseResult:  # fmt: skip
    """Convert ``path`` in a forked child; classify the result (see the module docstring)."""
    shutil.rmtree(out_dir, ignore_errors=True)
    out_dir.mkdir(parents=True)
    r, w = os.pipe()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(r)
        try:
            _child(path, out_dir, mem_limit_mb << 20, timeout_s, w)
        finally:
            os._exit(70)
    os.close(w)
    chunks = []
    while True:
        b = os.read(r, 65536)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    _, status, ru = os.wait4(pid, 0)
    secs = time.monotonic() - t0
    rss = ru.ru_maxrss / 1024
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        if sig == signal.SIGALRM:
            return CaseResult("timeout", f"over {timeout_s} s", secs, rss)
        if sig == signal.SIGKILL:
            return CaseResult("memory", "killed", secs, rss)
        return CaseResult("crash", signal.Signals(sig).name, secs, rss)
    if not chunks:
        return CaseResult("crash", f"exit status {os.WEXITSTATUS(status)}, no report", secs, rss)
    outcome, msg = json.loads(b"".join(chunks))
    if outcome in ("ok", "clean") and rss > rss_limit_mb:
        outcome, msg = "bigrss", f"{rss:.0f} MB ({outcome}: {msg[:100]})"
    return CaseResult(outcome, msg, secs, rss)


def warm_up() -> None:
    """Import the readers and compile their numba kernels once, before forking."""
    import tempfile

    from evdense.io.ingest import ingest_recording

    with tempfile.TemporaryDirectory() as d:
        for seed in make_seeds(Path(d) / "seeds"):
            try:
                ingest_recording(seed.path, Path(d) / "out" / f"{seed.name}.h5")
            except ValueError:
                pass


def fuzz(seeds: list[Seed], cases_per_seed: int, work: Path, seed: int = 0, **limits) -> dict:
    """Run ``cases_per_seed`` mutants of every seed; per-seed outcome counts and bad examples."""
    report: dict[str, dict] = {}
    for k, s in enumerate(seeds):
        rng = np.random.default_rng([seed, k])
        counts = dict.fromkeys(OUTCOMES, 0)
        bad: list[str] = []
        worst_rss = 0.0
        for i in range(cases_per_seed):
            mutant = write_mutant(s, work / "case", rng)
            res = run_case(mutant, work / "out", **limits)
            counts[res.outcome] += 1
            worst_rss = max(worst_rss, res.rss_mb)
            if res.outcome in BAD_OUTCOMES and len(bad) < 5:
                keep = work / "bad" / f"{s.name}_{i}"
                shutil.rmtree(keep, ignore_errors=True)
                shutil.copytree(work / "case", keep)
                bad.append(f"{res.outcome}: {res.message} ({keep})")
        report[s.name] = {"counts": counts, "max_rss_mb": worst_rss, "examples": bad}
    return report
