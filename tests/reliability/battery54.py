"""Issue 54's fault battery against the command line, on issue 33's harness (battery.py).

    python tests/reliability/battery54.py [--scratch DIR] [--keep] [--only NAME,...]

Not collected by pytest (no ``test_`` prefix). ``--only`` takes group names (issue 33's:
containment, writers, ...; issue 54's: loss54, hangs54, tracebacks54, silent54,
unclear54) or the names of issue 54's case functions (``python battery54.py --list``);
without it every old and every new case runs on one tiny base study, and the counts are
printed for the old cases, the new ones and all of them.

Every new case works in a folder of its own, ``cases/<case>/``, holding a canary file
beside (``canary-beside.txt``) and inside (``user/canary-inside.txt``, or
``run/canary-inside.txt`` in a copy of the base study) the folder the command is given;
a canary, or a file of the user's the case plants, changed or gone is ``data loss``.
Cases that need minutes (a placement of several studies, a kill -9 during placement)
are ``n/a`` here, naming the test that covers them.
"""

from __future__ import annotations

import argparse
import collections
import http.server
import json
import os
import shutil
import signal
import socket
import socketserver
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.reliability.battery import (  # noqa: E402 - after the path
    GROUPS as OLD_GROUPS,
)
from tests.reliability.battery import (  # noqa: E402
    OUTCOMES,
    TINY,
    Battery,
    Case,
    Result,
    _kept,
    _snapshot,
)

CANARY = b"the user's canary: it must survive\n"
SWEEP = ROOT / "configs" / "sweep_example.toml"
PLACEMENT = ROOT / "configs" / "placement_example.toml"


class Battery54(Battery):
    """The harness, with a command's pre-exec hook (an address-space limit)."""

    def cli(self, *args, timeout: float | None = None, env=None, preexec_fn=None) -> Result:
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "pipeline", *map(str, args)], cwd=self.scratch,
                                env=env or self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True, preexec_fn=preexec_fn)
        try:
            out, _ = proc.communicate(timeout=timeout or self.timeout)
            return Result(proc.returncode, out, time.monotonic() - t0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the process group this call started
            out, _ = proc.communicate()
            return Result(None, out, time.monotonic() - t0)


# -- the cases' folders ---------------------------------------------------------------------
def nest(b: Battery, slug: str) -> tuple[Path, Path]:
    """``cases/<slug>/`` with a canary, and its ``user/`` folder with another."""
    parent = b.scratch / "cases" / slug
    user = parent / "user"
    user.mkdir(parents=True)
    (parent / "canary-beside.txt").write_bytes(CANARY)
    (user / "canary-inside.txt").write_bytes(CANARY)
    return parent, user


def run_copy(b: Battery, slug: str, name: str = "run") -> tuple[Path, Path]:
    """``cases/<slug>/`` with a canary, and in it a copy of the base study with another."""
    parent = b.scratch / "cases" / slug
    parent.mkdir(parents=True, exist_ok=True)
    run = parent / name
    shutil.copytree(b.base, run, symlinks=True)
    (run / ".rfidstudy.lock").unlink(missing_ok=True)
    (parent / "canary-beside.txt").write_bytes(CANARY)
    (run / "canary-inside.txt").write_bytes(CANARY)
    return parent, run


def canaries_kept(parent: Path) -> bool:
    return all(p.is_file() and not p.is_symlink() and p.read_bytes() == CANARY
               for p in [parent / "canary-beside.txt", *parent.glob("*/canary-inside.txt")])


def kept(parent: Path, before: dict) -> bool:
    return _kept(parent, before) and canaries_kept(parent)


def error_words_only(c: Case, *bad: str) -> None:
    """A clear error that still says one of ``bad`` (an old wording) is unclear."""
    if c.outcome == "clear error" and any(w in c.detail for w in bad):
        c.outcome = "unclear"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- maps -----------------------------------------------------------------------------------
def small_map(folder: Path, name: str = "site", **keys) -> Path:
    """A 13 x 9 m building map (tests/scenes/maphelpers.py), YAML keys overridden."""
    from tests.scenes.maphelpers import building, write_map

    return write_map(folder, building(width_m=12.0, length_m=8.0, wall_m=0.25, pad_m=0.5),
                     name=name, **keys)


def map_yaml(folder: Path, name: str, text: str) -> Path:
    p = folder / f"{name}.yaml"
    p.write_text(text)
    return p


def laughs(indent: str = "") -> str:
    """A billion laughs: nine levels of nine aliases (9**9 strings, a few hundred bytes)."""
    rows = [f'{indent}- &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for prev, cur in zip("abcdefgh", "bcdefghi", strict=True):
        rows.append(f"{indent}- &{cur} [" + ", ".join([f"*{prev}"] * 9) + "]")
    return "\n".join(rows) + "\n"


def sparse_pgm(path: Path, w: int, h: int) -> None:
    """A binary PGM of ``w`` x ``h`` pixels, all zero, as a sparse file (no disk used)."""
    head = f"P5\n{w} {h}\n255\n".encode()
    with open(path, "wb") as fh:
        fh.write(head)
        fh.truncate(len(head) + w * h)


def big_png(path: Path, w: int, h: int, value: int = 254) -> None:
    """A valid 8-bit grey PNG of ``w`` x ``h`` pixels, compressed row by row (small file)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    co = zlib.compressobj(6)
    row = b"\x00" + bytes([value]) * w
    parts = [co.compress(row) for _ in range(h)]
    parts.append(co.flush())
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))


def map_case(b: Battery, slug: str, title: str, yaml_text: str, words, *, timeout=120,
             via_toml: bool = False, prepare=None, expect: str = "error") -> Case:
    """``scenes show`` on a map YAML (or a scene TOML whose ``[map] path`` names it)."""
    parent, user = nest(b, slug)
    if prepare is not None:
        prepare(user)
    target = map_yaml(user, "map", yaml_text.replace("@USER@", str(user)))
    if via_toml:
        (user / "scene.toml").write_text(f'name = "site"\n[map]\npath = "{target.name}"\n')
        target = user / "scene.toml"
    before = _snapshot(parent)
    c = Case(title, expect, tuple(words))
    res = b.cli("scenes", "show", target, timeout=timeout)
    b.classify(c, res, intact=kept(parent, before))
    c.detail = f"[{res.seconds:.0f} s] {c.detail}"
    return c


GOOD_KEYS = "resolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"


def yaml_with(image: str = "site.pgm", **over) -> str:
    keys = {"image": image, "resolution": "0.05", "origin": "[0.0, 0.0, 0.0]", "negate": "0",
            "occupied_thresh": "0.65", "free_thresh": "0.196", **over}
    return "".join(f"{k}: {v}\n" for k, v in keys.items())


# -- registry -------------------------------------------------------------------------------
NEW: dict[str, tuple[str, object]] = {}


def case(group: str):
    def deco(fn):
        NEW[fn.__name__] = (group, fn)
        return fn
    return deco


# ===========================================================================================
# Data loss
# ===========================================================================================
def _plant_foreign(user: Path, plant: str) -> None:
    if plant.endswith("manifest.json"):
        (user / "manifest.json").write_text(json.dumps({"name": "My App", "start_url": "/", "icons": []}))
    else:
        (user / "stages").mkdir()
    (user / "report.html").write_text("<p>my page</p>")
    (user / "config.toml").write_text('title = "my site"\n')


@case("loss54")
def report_figures_on_a_foreign_folder(b):
    out = []
    for plant in ("a web-app manifest.json", "an empty stages/"):
        for command in ("report", "figures"):
            parent, user = nest(b, f"{command}_{plant.split()[1].strip('/').replace('.', '_')}")
            _plant_foreign(user, plant)
            before = _snapshot(parent)
            c = Case(f"{command} DIR holding {plant}", "error", ("not a run directory",))
            b.classify(c, b.cli(command, user, timeout=90), intact=kept(parent, before))
            out.append(c)
    return out


@case("loss54")
def run_out_on_a_foreign_folder(b):
    out = []
    for plant in ("a web-app manifest.json", "an empty stages/"):
        parent, user = nest(b, f"run_out_{plant.split()[1].strip('/').replace('.', '_')}")
        _plant_foreign(user, plant)
        before = _snapshot(parent)
        c = Case(f"run --out DIR holding {plant}", "error", ("not a run directory",))
        res = b.run(user, timeout=150)
        b.classify(c, res, intact=kept(parent, before))
        out.append(c)
    return out


@case("loss54")
def sweep_out_with_a_users_sweep_json(b):
    parent, user = nest(b, "sweep_own_json")
    (user / "sweep.json").write_text('{"mine": true}\n')
    (user / "summary.csv").write_text("my,table\n1,2\n")
    before = _snapshot(parent)
    c = Case("sweep --out DIR with the user's sweep.json", "error", ("not a sweep",))
    b.classify(c, b.cli("sweep", SWEEP, "--out", user, timeout=120), intact=kept(parent, before))
    return [c]


@case("loss54")
def placement_out_with_a_users_placement_json(b):
    parent, user = nest(b, "placement_own_json")
    (user / "placement.json").write_text('{"mine": true}\n')
    (user / "ranking.csv").write_text("my,ranking\n")
    (user / "placement").mkdir()
    (user / "placement" / "ranking.csv").write_text("my,ranking\n")
    before = _snapshot(parent)
    c = Case("placement --out DIR with the user's placement.json", "error", ("not a placement",))
    b.classify(c, b.cli("placement", PLACEMENT, "--out", user, timeout=120), intact=kept(parent, before))
    return [c]


@case("loss54")
def compare_out_a_users_folder(b):
    parent, user = nest(b, "compare_user")
    (user / "compare.csv").write_text("my,comparison\n")
    (user / "compare.pdf").write_bytes(b"%PDF-1.4 my own pdf\n")
    before = _snapshot(parent)
    c = Case("compare --out USERDIR with compare.csv/.pdf", "error",
             ("compare.csv", "compare.pdf", "not a", "of yours"))
    b.classify(c, b.cli("compare", b.base, b.base, "--out", user, timeout=90), intact=kept(parent, before))
    return [c]


@case("loss54")
def figures_only_out_a_users_folder(b):
    parent, user = nest(b, "figures_only_user")
    (user / "baselines.pdf").write_bytes(b"%PDF-1.4 my baselines\n")
    (user / "baselines.png").write_bytes(b"\x89PNG my baselines\n")
    before = _snapshot(parent)
    c = Case("figures RUN --only baselines --out USERDIR", "error",
             ("baselines.pdf", "baselines.png", "not a", "of yours"))
    b.classify(c, b.cli("figures", b.base, "--only", "baselines", "--out", user, timeout=120),
               intact=kept(parent, before))
    return [c]


@case("loss54")
def scenes_show_png_beside_a_users_pdf(b):
    parent, user = nest(b, "show_png")
    (user / "top.pdf").write_bytes(b"%PDF-1.4 my top view\n")
    before = _snapshot(parent)
    c = Case("scenes show --png DIR/top.png (user's top.pdf)", "ok")
    res = b.cli("scenes", "show", "corridor_lab", "--png", user / "top.png", timeout=90)
    b.classify(c, res, intact=kept(parent, before), right=(user / "top.png").is_file())
    return [c]


# ===========================================================================================
# Hangs and exhaustion
# ===========================================================================================
@case("hangs54")
def scene_with_100k_tags(b):
    parent, user = nest(b, "tags_100k")
    rows = "".join(f'{{ id = "T{i}", position_m = [{(i % 240) / 10:.1f}, 0.0, 1.0], '
                   f"normal = [0.0, 1.0, 0.0] }},\n" for i in range(100_000))
    (user / "scene.toml").write_text(f'name = "many"\ntag = [\n{rows}]\n[corridor]\nlength_m = 25.0\n'
                                     "width_m = 2.4\nheight_m = 3.0\n")
    before = _snapshot(parent)
    c = Case("scene TOML with 100,000 tags: scenes show", "error", ("100,000", "MAX_TAGS"))
    res = b.cli("scenes", "show", user / "scene.toml", timeout=120)
    b.classify(c, res, intact=kept(parent, before))
    c.detail = f"[{res.seconds:.0f} s] {c.detail}"
    return [c]


def _placement_file(user: Path, body: str) -> Path:
    p = user / "placement.toml"
    p.write_text(f'base = "{TINY}"\nreplicates = 3\npareto = ["read_rate", "rssi_rmse_db"]\n'
                 f"{body}\n[study.downstream]\nenabled = false\n")
    return p


def placement_refusal(b, slug: str, title: str, body: str, words, timeout=120) -> Case:
    """A placement file that must be refused before any study starts."""
    parent, user = nest(b, slug)
    spec = _placement_file(user, body)
    before = _snapshot(parent)
    c = Case(title, "error", tuple(words))
    out = user / "out"
    res = b.cli("placement", spec, "--out", out, "--workers", "1", timeout=timeout)
    b.classify(c, res, intact=kept(parent, before))
    started = list(out.glob("candidates/*/*/stages"))
    if res.rc is None and started:
        c.outcome, c.detail = "silent accept", f"{len(started)} studies started, no refusal"
    elif c.outcome == "clear error" and started:
        c.outcome, c.detail = "unclear", "refused only after studies started: " + c.detail
    c.detail = f"[{res.seconds:.0f} s] {c.detail}"
    return c


@case("hangs54")
def placement_grid_1000x1000(b):
    z = [round(0.3 + 1.2 * i / 999, 6) for i in range(1000)]
    t = [round(-30.0 + 60.0 * i / 999, 6) for i in range(1000)]
    return [placement_refusal(b, "grid_1000x1000", "placement grid 1000 x 1000", f"[grid]\nz_m = {z}\n"
                              f"tilt_deg = {t}\n", ("candidates", "MAX_CANDIDATES"))]


@case("hangs54")
def billion_laughs(b):
    out = []
    base = yaml_with()
    list_key = base + "laughs:\n" + laughs("  ")
    under_origin = yaml_with(origin="\n" + laughs("  ")).replace("origin: \n", "origin:\n")
    for title, text, via in (("billion-laughs map YAML under a list key", list_key, False),
                             ("billion-laughs map YAML under origin:", under_origin, False),
                             ("billion laughs through a scene TOML's [map] path", list_key, True)):
        out.append(map_case(b, f"laughs_{len(out)}", title, text, ("alias",), via_toml=via,
                            prepare=lambda u: small_map(u)))
    return out


@case("hangs54")
def map_image_12000x12000(b):
    return [map_case(b, "map_12000", "map image 12000 x 12000 (PGM)", yaml_with("big.pgm"),
                     ("pixels", "MAX_PIXELS"), prepare=lambda u: sparse_pgm(u / "big.pgm", 12000, 12000))]


class _Hello(http.server.BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802 - http.server's name
        body = b"<html>hello</html>"
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


class _Junk(socketserver.BaseRequestHandler):
    """A server that answers every connection with bytes no Dask scheduler sends."""

    def handle(self):
        try:
            self.request.sendall(b"\xff\xff\xff\xff\xff\xff\xff\x2f" + os.urandom(4096))
            self.request.settimeout(30)
            while self.request.recv(65536):
                pass
        except OSError:
            pass


def _serve(server) -> socketserver.BaseServer:
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def scheduler_case(b, slug: str, title: str, command: str, address: str, words, timeout=120) -> Case:
    parent, user = nest(b, slug)
    before = _snapshot(parent)
    c = Case(title, "error", tuple(words))
    out = user / "out"
    if command == "sweep":
        args = ("sweep", SWEEP, "--out", out)
    elif command == "placement":
        args = ("placement", PLACEMENT, "--out", out)
    else:
        args = ("run", TINY, "--no-progress", "--out", out)
    res = b.cli(*args, "--scheduler", address, timeout=timeout)
    b.classify(c, res, intact=kept(parent, before))
    if c.outcome in ("clear error", "unclear") and (list(out.glob("runs/*/stages/tour.json"))
                                                    or (out / "stages" / "tour.json").exists()):
        c.outcome, c.detail = "unclear", "refused only after work: " + c.detail
    c.detail = f"[{res.seconds:.0f} s] {c.detail}"
    return c


@case("hangs54")
def scheduler_at_a_web_server(b):
    server = _serve(http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Hello))
    try:
        return [scheduler_case(b, "sched_http", "sweep --scheduler at a plain HTTP server", "sweep",
                               f"tcp://127.0.0.1:{server.server_address[1]}", ("not a Dask scheduler",))]
    finally:
        server.shutdown()


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            pids.append(int(d.name))
    return pids


@case("hangs54")
def kill9_of_a_replicated_run(b):
    """kill -9 of ``run --replicates 3``'s main process once its workers run: none of them
    may still live 20 s later (issue 54: they finished their studies and idled at 1 GB)."""
    parent, user = nest(b, "kill9_replicates")
    before = _snapshot(parent)
    c = Case("kill -9 of run --replicates 3: workers die", "ok")
    out = user / "out"
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", "run", str(TINY), "--no-progress",
                             "--replicates", "3", "--out", str(out)], cwd=b.scratch, env=b.env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        t0, seen = time.monotonic(), None
        while time.monotonic() - t0 < 90 and proc.poll() is None:
            others = [p for p in _group_members(proc.pid) if p != proc.pid]
            if others and seen is None:
                seen = time.monotonic()
            if seen is not None and time.monotonic() - seen > 15:  # the workers are at work
                break
            time.sleep(0.5)
        if proc.poll() is not None or seen is None:
            c.outcome, c.detail = "n/a", f"no worker process seen (rc {proc.poll()})"
            return [c]
        workers = [p for p in _group_members(proc.pid) if p != proc.pid]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        t1 = time.monotonic()
        while time.monotonic() - t1 < 20 and _group_members(proc.pid):
            time.sleep(0.5)
        left = _group_members(proc.pid)
        if left:
            c.outcome = "hang"
            c.detail = f"{len(left)} of {len(workers)} worker processes alive 20 s after kill -9: {left}"
        elif not kept(parent, before):
            c.outcome, c.detail = "data loss", "a canary changed"
        else:
            c.outcome = "ok"
            c.detail = f"{len(workers)} worker processes gone {time.monotonic() - t1:.1f} s after kill -9"
    finally:
        if _group_members(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)  # the group this case started
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return [c]


@case("hangs54")
def slow_kill_and_rerun_cases(b):
    out = []
    for title, test in (
            ("kill -9 of placement: workers die, rerun ranks nothing",
             "test_orphans.py::test_a_sweep_worker_dies_with_its_killed_parent and "
             "::test_placement_ranks_nothing_while_an_earlier_worker_writes_a_candidate (slow)"),
            ("rerun while a killed run's worker writes: no pooling",
             "test_orphans.py::test_replicates_are_not_pooled_while_an_earlier_worker_writes_one "
             "(slow)")):
        c = Case(title, "ok", outcome="n/a")
        c.detail = f"minutes of studies; covered by tests/reliability/{test}"
        out.append(c)
    return out


# ===========================================================================================
# Tracebacks
# ===========================================================================================
@case("tracebacks54")
def map_png_20000x20000(b):
    return [map_case(b, "map_20000", "map PNG 20000 x 20000 (decompression bomb)", yaml_with("big.png"),
                     ("pixels", "MAX_PIXELS"), prepare=lambda u: big_png(u / "big.png", 20000, 20000))]


@case("tracebacks54")
def map_resolution_tiny(b):
    out = []
    for value in ("1.0e-9", "0.0001"):
        out.append(map_case(b, f"res_{value}", f"map resolution: {value}", yaml_with(resolution=value),
                            ("resolution",), prepare=lambda u: small_map(u)))
    return out


@case("tracebacks54")
def map_origin_1e300(b):
    return [map_case(b, "origin_1e300", "map origin: [1e300, 0, 0]",
                     yaml_with(origin="[1.0e+300, 0.0, 0.0]"), ("origin",), prepare=lambda u: small_map(u))]


@case("tracebacks54")
def out_through_a_symlink_loop(b):
    out = []
    for command in ("placement", "compare"):
        parent, user = nest(b, f"loop_{command}")
        loop = user / "loop"
        loop.symlink_to(loop)
        before = _snapshot(parent)
        c = Case(f"{command} --out through a symlink loop", "error", ("loop", "cannot be resolved",
                                                                      "cannot be used"))
        args = ("placement", PLACEMENT) if command == "placement" else ("compare", b.base, b.base)
        b.classify(c, b.cli(*args, "--out", loop / "x", timeout=90), intact=kept(parent, before))
        out.append(c)
    return out


@case("tracebacks54")
def scheduler_a_file(b):
    parent, user = nest(b, "sched_file_addr")
    f = user / "scheduler.json"
    f.write_text('{"address": "tcp://127.0.0.1:8786"}\n')
    c = scheduler_case(b, "sched_file", "sweep --scheduler FILE", "sweep", str(f),
                       ("a path on this machine",), timeout=90)
    if f.read_text() != '{"address": "tcp://127.0.0.1:8786"}\n' or not canaries_kept(parent):
        c.outcome = "data loss"
    return [c]


@case("tracebacks54")
def scheduler_unreachable(b):
    return [scheduler_case(b, f"sched_unreach_{cmd}", f"{cmd} --scheduler unreachable", cmd,
                           f"tcp://127.0.0.1:{_free_port()}", ("unreachable",), timeout=120)
            for cmd in ("sweep", "placement")]


# ===========================================================================================
# Silent
# ===========================================================================================
def _leaves(x, prefix=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, f"{prefix}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, f"{prefix}/{i}")
    else:
        yield prefix, x


@case("silent54")
def tampered_cache_pack(b):
    """A cache pack re-saved with gains x 1.2 and its checksum recomputed: unkeyed
    checksums cannot see it; issue 54 accepts either a keyed checksum or the README
    saying so ("safe to receive"). ``ok`` only if refused, or used and documented."""
    import numpy as np

    from propagation.pathcache import values_sha256

    parent, run = run_copy(b, "tampered_pack")
    cache = parent / "cache"
    shutil.copytree(b.scratch / "cache", cache)
    packs = sorted(cache.rglob("pack-*.json"))
    c = Case("cache pack re-saved x1.2, checksum recomputed", "ok")
    if not packs:
        c.outcome, c.detail = "n/a", "no cache pack"
        return [c]
    for js in packs:
        npz = js.with_suffix(".npz")
        with np.load(npz, allow_pickle=False) as z:
            arr = {k: z[k] for k in z.files}
        arr["transfer_re"] = np.ascontiguousarray(arr["transfer_re"] * np.float32(1.2))
        arr["transfer_im"] = np.ascontiguousarray(arr["transfer_im"] * np.float32(1.2))
        np.savez_compressed(npz, **arr)
        meta = json.loads(js.read_text())
        meta["sha256"] = values_sha256(arr)
        js.write_text(json.dumps(meta))
    want = dict(_leaves(json.loads((run / "metrics.json").read_text())))
    res = b.run(run, "--force", "reads", timeout=300, env={**b.env, "RFIDSTUDY_CACHE": str(cache)})
    got = dict(_leaves(json.loads((run / "metrics.json").read_text()))) if res.rc == 0 else {}
    changed = sum(1 for k, v in want.items() if got.get(k, v) != v)
    b.classify(c, res, intact=canaries_kept(parent))
    refused = "CacheWarning" in res.out or "checksum" in res.out.lower()
    readme = (ROOT / "README.md").read_text()
    documented = "do **not** guard" in readme and "tampering" in readme
    if c.outcome == "ok":
        if refused:
            c.detail = "the tampered pack was refused and re-traced"
        elif changed and documented:
            c.detail = (f"documented limitation: used, {changed} of {len(want)} metrics changed (README 'safe "
                        "to receive': unkeyed checksums, not against tampering)")
        elif changed:
            c.outcome, c.detail = "silent wrong", f"used: {changed} of {len(want)} metrics changed"
        else:
            c.detail = "metrics unchanged (the pack was not read?)"
    c.detail = f"[{res.seconds:.0f} s] {c.detail}"
    return [c]


@case("silent54")
def placement_counts(b):
    z = [round(0.3 + 1.2 * i / 99, 6) for i in range(100)]
    t = [round(-30.0 + 60.0 * i / 99, 6) for i in range(100)]
    one = Case("placement with one candidate: no runner-up claim", "ok", outcome="n/a")
    one.detail = ("2+ studies (minutes); covered by tests/pipeline/placement/test_placement_spec.py::"
                  "test_a_preset_name_is_used_as_given_or_refused (answer_lines: 'nothing to compare')")
    return [
        placement_refusal(b, "grid_100x100", "placement of 10,000 candidates (x3 replicates)",
                          f"[grid]\nz_m = {z}\ntilt_deg = {t}\n", ("candidates", "MAX_CANDIDATES")),
        placement_refusal(b, "n_trials_neg", "placement n_trials = -3 beside a grid",
                          "[grid]\ntilt_deg = [0.0, 20.0]\n[optimise]\nn_trials = -3\n"
                          "[optimise.ranges]\ntilt_deg = [-30.0, 30.0]\n", ("n_trials",)),
        placement_refusal(b, "preset_abs", "placement preset named /tmp/evil",
                          '[[preset]]\nname = "/tmp/evil"\n[[preset.antennas]]\nname = "a"\nz_m = 0.7\n',
                          ("preset[0].name",)),
        one,
    ]


@case("silent54")
def compare_out_inside_another_run(b):
    out = []
    parent, other = run_copy(b, "compare_into_run", "other")
    for where in ("", "figures", "stages"):
        target = other / where if where else other
        before = _snapshot(parent)
        c = Case(f"compare --out another run's {where or 'root'}{'/' if where else ''}", "error",
                 ("run directory", "inside"))
        res = b.cli("compare", b.base, b.base, "--out", target, timeout=90)
        new = sorted(p.name for p in target.glob("compare*"))
        b.classify(c, res, intact=kept(parent, before))
        if new and c.outcome not in ("data loss",):
            c.outcome, c.detail = ("silent accept" if res.rc == 0 else c.outcome), f"wrote {new}; {c.detail}"
        out.append(c)
    return out


@case("silent54")
def figures_out_the_runs_root(b):
    parent, run = run_copy(b, "figures_out_root")
    before = _snapshot(parent)
    c = Case("figures RUN --out RUN (its root)", "error", ("--out", "run directory"))
    b.classify(c, b.cli("figures", run, "--only", "baselines", "--out", run, timeout=120),
               intact=kept(parent, before))
    return [c]


@case("silent54")
def scheduler_empty(b):
    return [scheduler_case(b, "sched_empty", "run --scheduler ''", "run", "", ("empty address",), timeout=150)]


# ===========================================================================================
# Unclear
# ===========================================================================================
@case("unclear54")
def map_resolution_yaml11(b):
    bad = map_case(b, "res_1e-9", "map resolution: 1e-9 (YAML 1.1: a string)",
                   yaml_with(resolution="1e-9"), ("resolution",), prepare=lambda u: small_map(u))
    error_words_only(bad, "got '1e-9'", "finite number")
    good = map_case(b, "res_5e-2", "map resolution: 5e-2 (ROS reads 0.05)", yaml_with(resolution="5e-2"),
                    (), prepare=lambda u: small_map(u), expect="ok")
    return [bad, good]


def _passwd_echo(text: str) -> bool:
    try:
        lines = [ln for ln in Path("/etc/passwd").read_text(errors="replace").splitlines() if len(ln) > 8]
    except OSError:
        return False
    # as tests/reliability/test_no_echo.py: at most a 60-character prefix of the first line
    return any(ln in text for ln in lines[1:]) or (bool(lines) and len(lines[0]) > 60
                                                   and lines[0][:61] in text)


@case("unclear54")
def etc_passwd_as_map_or_tag_csv(b):
    out = []
    if not Path("/etc/passwd").is_file():
        c = Case("[map] path / tag CSV = /etc/passwd", "error", outcome="n/a", detail="no /etc/passwd")
        return [c]
    for key in ("map", "csv"):
        parent, user = nest(b, f"passwd_{key}")
        if key == "map":
            toml = 'name = "site"\n[map]\npath = "/etc/passwd"\n'
        else:
            small_map(user)
            toml = 'name = "site"\n[map]\npath = "site.yaml"\n[tags]\nlayout = "csv"\ncsv = "/etc/passwd"\n'
        (user / "scene.toml").write_text(toml)
        before = _snapshot(parent)
        c = Case(f"{'[map] path' if key == 'map' else 'tag CSV'} = /etc/passwd: scenes show", "error",
                 ("/etc/passwd",))
        res = b.cli("scenes", "show", user / "scene.toml", timeout=90)
        b.classify(c, res, intact=kept(parent, before))
        if _passwd_echo(res.out) and c.outcome == "clear error":
            c.outcome, c.detail = "unclear", "echoes /etc/passwd: " + c.detail
        out.append(c)
    return out


@case("unclear54")
def map_image_not_a_file(b):
    out = []

    def fifo(u):
        small_map(u)
        os.mkfifo(u / "fifo.pgm")

    def folder(u):
        small_map(u)
        (u / "folder.pgm").mkdir()

    for label, image, prep in (("/dev/zero", "/dev/zero", lambda u: small_map(u)),
                               ("a FIFO", "fifo.pgm", fifo), ("a directory", "folder.pgm", folder)):
        c = map_case(b, f"image_{len(out)}", f"map image at {label}", yaml_with(image), ("not a regular file",),
                     prepare=prep, timeout=60)
        error_words_only(c, "does not exist")
        out.append(c)
    return out


@case("unclear54")
def ulimit_below_the_budget(b):
    limit = 2560 * 2**20

    def cap():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    parent, user = nest(b, "ulimit")
    before = _snapshot(parent)
    c = Case("run under ulimit -v 2560 MiB (budget 2,048 MiB)", "error", ("memory_budget_mb",))
    env = {**b.env, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    res = b.cli("run", TINY, "--no-progress", "--out", user / "out", timeout=150, env=env, preexec_fn=cap)
    b.classify(c, res, intact=kept(parent, before))
    if res.rc is not None and res.rc < 0 or res.rc == 139:
        c.outcome, c.detail = "unclear", f"killed by signal (rc {res.rc}): {c.detail}"
    return [c]


@case("unclear54")
def scheduler_answering_junk(b):
    server = _serve(socketserver.ThreadingTCPServer(("127.0.0.1", 0), _Junk))
    try:
        c = scheduler_case(b, "sched_junk", "sweep --scheduler answering non-Dask bytes", "sweep",
                           f"tcp://127.0.0.1:{server.server_address[1]}", ("not a Dask scheduler",))
        error_words_only(c, "EiB", "allocate")
        return [c]
    finally:
        server.shutdown()


@case("unclear54")
def scene_length_1e300(b):
    parent, user = nest(b, "length_1e300")
    (user / "scene.toml").write_text('name = "huge"\n[corridor]\nlength_m = 1e300\nwidth_m = 2.4\n'
                                     "height_m = 3.0\n")
    before = _snapshot(parent)
    c = Case("scene corridor length_m = 1e300: scenes show", "error", ("length_m",))
    b.classify(c, b.cli("scenes", "show", user / "scene.toml", timeout=90), intact=kept(parent, before))
    return [c]


@case("unclear54")
def bad_frequency_in_a_runs_config(b):
    parent, run = run_copy(b, "bad_frequency")
    cfg = run / "config.toml"
    text = cfg.read_text()
    c = Case("frequency_hz = -1 in a run's config.toml: report", "error", ("frequency_hz",))
    if "\nfrequency_hz = " not in text:
        c.outcome, c.detail = "n/a", "no frequency_hz line in config.toml"
        return [c]
    cfg.write_text(text.replace("\nfrequency_hz = ", "\nfrequency_hz = -1.0\n#", 1))
    b.classify(c, b.cli("report", run, timeout=90), intact=canaries_kept(parent))
    return [c]


@case("unclear54")
def png_under_a_file(b):
    parent, user = nest(b, "png_under_file")
    (user / "afile").write_text("mine\n")
    before = _snapshot(parent)
    c = Case("scenes show --png FILE/x.png", "error", ("--png",))
    b.classify(c, b.cli("scenes", "show", "corridor_lab", "--png", user / "afile" / "x.png", timeout=90),
               intact=kept(parent, before))
    return [c]


@case("unclear54")
def compare_out_a_file(b):
    parent, user = nest(b, "compare_out_file")
    (user / "afile").write_text("mine\n")
    before = _snapshot(parent)
    c = Case("compare --out FILE", "error", ("not a directory", "a file"))
    b.classify(c, b.cli("compare", b.base, b.base, "--out", user / "afile", timeout=90),
               intact=kept(parent, before))
    return [c]


@case("unclear54")
def metrics_json_a_fifo(b):
    out = []
    parent, run = run_copy(b, "metrics_fifo")
    (run / "metrics.json").unlink()
    os.mkfifo(run / "metrics.json")
    for command in ("report", "compare"):
        c = Case(f"metrics.json a FIFO: {command}", "error", ("not a regular file",))
        args = ("report", run) if command == "report" else ("compare", run, b.base, "--out",
                                                            parent / "cmp")
        b.classify(c, b.cli(*args, timeout=60), intact=canaries_kept(parent))
        out.append(c)
    return out


@case("unclear54")
def placement_json_a_link(b):
    parent, user = nest(b, "placement_link")
    mark = parent / "elsewhere.json"
    mark.write_text('{"tool": "rfidstudy", "kind": "placement"}')
    (user / "placement.json").symlink_to(mark)
    before = _snapshot(parent)
    c = Case("placement --out DIR whose placement.json is a link", "error", ("symbolic link",))
    b.classify(c, b.cli("placement", PLACEMENT, "--out", user, timeout=90), intact=kept(parent, before))
    if c.outcome == "clear error" and sorted(p.name for p in user.iterdir()) != ["canary-inside.txt",
                                                                                 "placement.json"]:
        c.outcome, c.detail = "unclear", "refused, but wrote into the folder: " + c.detail
    return [c]


NEW_GROUPS = ("loss54", "hangs54", "tracebacks54", "silent54", "unclear54")


def _print(c: Case) -> None:
    print(f"{c.outcome:13s} {c.name[:50]:50s} {c.detail[:140]}", flush=True)


def _counts(title: str, cases: list[Case]) -> None:
    counts = collections.Counter(c.outcome for c in cases)
    print(f"{title}: {len(cases)} cases")
    for o in OUTCOMES:
        print(f"  {o:13s} {counts.get(o, 0)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scratch", type=Path, help="scratch directory (default: a new temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch directory")
    ap.add_argument("--only", help="comma-separated groups or case names (--list)")
    ap.add_argument("--list", action="store_true", help="list the groups and case names and exit")
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds per command (hang beyond)")
    args = ap.parse_args(argv)
    if args.list:
        print("issue 33 groups:", ", ".join(OLD_GROUPS))
        for g in NEW_GROUPS:
            print(f"{g}: {', '.join(n for n, (grp, _) in NEW.items() if grp == g)}")
        return 0
    wanted = args.only.split(",") if args.only else [*OLD_GROUPS, *NEW_GROUPS]
    unknown = [w for w in wanted if w not in OLD_GROUPS and w not in NEW_GROUPS and w not in NEW]
    if unknown:
        ap.error(f"unknown group or case: {', '.join(unknown)} (see --list)")
    scratch = (args.scratch or Path(tempfile.mkdtemp(prefix="rfidstudy-battery54-"))).resolve()
    scratch.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(scratch / "cases", ignore_errors=True)  # a kept scratch: its base is reused
    (scratch / "cases").mkdir()
    b = Battery54(scratch, args.timeout)
    t0 = time.monotonic()
    try:
        res = b.run(b.base, timeout=900)
        if res.rc != 0:
            print(f"the base study failed:\n{res.out}")
            return 1
        print(f"base study in {res.seconds:.0f} s; scratch {scratch}", flush=True)
        old: list[Case] = []
        new: list[Case] = []
        for w in wanted:
            if w in OLD_GROUPS:
                for c in OLD_GROUPS[w](b):
                    old.append(c)
                    _print(c)
                continue
            fns = [fn for name, (grp, fn) in NEW.items() if w in (grp, name)]
            for fn in fns:
                try:
                    got = fn(b)
                except Exception as exc:  # noqa: BLE001 - a case that cannot be staged is n/a
                    got = [Case(fn.__name__, "ok", outcome="n/a",
                                detail=f"staging failed: {type(exc).__name__}: {exc}"[:200])]
                for c in got:
                    new.append(c)
                    _print(c)
        print(f"\n{len(old) + len(new)} cases in {time.monotonic() - t0:.0f} s")
        if old:
            _counts("issue 33 (old)", old)
        if new:
            _counts("issue 54 (new)", new)
        if old and new:
            _counts("all", old + new)
        bad = [c for c in old + new if c.outcome not in ("ok", "clear error", "n/a")]
        for c in bad:
            print(f"  ! {c.outcome}: {c.name}: {c.detail}")
        return 1 if bad else 0
    finally:
        if not args.keep:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
