"""Every reader against a generated corpus of hostile files (tests/support/hostile_corpus.py), through the command line.

Each case runs in its own process (forked from a server that imported the project once, see
tests/support/cli_forkserver.py) with an address-space limit (RLIMIT_AS: 1 GiB above what the process had) and a
generous wall-clock bound, and must end with exit status 2 and exactly one line on stderr naming the file: no
traceback, no native crash (death by a signal), no hang, no memory blow-up, nothing unpickled. Caches, which
have no command of their own, go through the reader the pose worker uses and must be refused (a miss). A few
cases also run through the real console entry point (`python -m npga_view.cli`) with the limit set in
preexec_fn. The number of cases per reader is printed (`pytest -s`) and checked to be at least 10.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from tests.support import hostile_corpus as hc
from tests.support import hostile_readers_corpus as hr
from tests.support.cli_forkserver import LIMIT_MB, TIMEOUT_S
from tests.support.hostile_readers_corpus import GHA_SMALL

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork server, FIFOs, RLIMIT_AS")

def _cli(argv: Callable[[Path, dict], list[str]], env: Callable[[Path], dict] | None = None,
         names: Callable[[Path], list[Path]] | None = None):
    """A reader reached through the command line: exit 2, one line naming the file."""
    return {"argv": argv, "env": env or (lambda p: {}), "names": names or (lambda p: [p]), "exit": 2}


def _accepted(argv: Callable[[Path, dict], list[str]]):
    """A valid but degenerate input: exit 0, no traceback, no warning on stderr."""
    return {"argv": argv, "env": lambda p: {}, "names": lambda p: [p], "exit": 0}


def _call(func: str, args: Callable[[Path, dict], list]):
    """A cache reader: refused (the function returns 0), silently."""
    return {"call": func, "args": args, "exit": 0}


def _partial(func: str, args: Callable[[Path, dict], list]):
    """A reader of folders of many files (captures): refused in one line naming a file (exit 2), or, for cases
    named "partial: ...", the usable part taken and each problem one line on stdout naming a file (exit 0), with
    nothing on stderr (no native library's warnings)."""
    return {"call": func, "args": args, "exit": lambda name: 0 if name.startswith("partial") else 2,
            "names": lambda p: [p]}


def _shrinking_argv(p: Path, w: dict) -> list[str]:
    out = str(w["root"] / "o.ply")
    argv = {".npga": ["info", str(p)], ".ply": ["info", str(p)], ".csv": ["export", str(w["avatar"]), "--out", out,
                                                                         "--sequence", str(p), "--frame", "0"],
            ".npy": ["export", str(w["avatar"]), "--out", out, "--expr", str(p)],
            ".npz": ["export", str(w["avatar"]), "--out", out, "--sequence", str(p), "--frame", "0"],
            ".json": ["render", str(w["avatar"]), "--camera", str(p), "--out", str(w["root"] / "o.png")]}[p.suffix]
    return [str(p), json.dumps(argv)]


def _shrinking_files(d: Path, w: dict) -> dict[str, Path]:
    """Valid files of every kind, each read while it shrinks to half (hr.while_shrinking)."""
    from npga_core.files.sequences import ExpressionSequence

    cases = {"avatar .npga": d / "a.npga", "avatar .ply": d / "a.ply", "codes .npy": d / "c.npy",
             "sequence .npz": d / "s.npz", "ARKit take .csv": d / "t.csv", "camera .json": d / "cam.json"}
    cases["avatar .npga"].write_bytes(w["avatar"].read_bytes())
    cases["avatar .ply"].write_bytes(w["ply"].read_bytes())
    np.save(cases["codes .npy"], np.zeros((400, w["dim"]), np.float32))
    ExpressionSequence(np.zeros((400, w["dim"]), np.float32), 25.0, "s").save(cases["sequence .npz"])
    rows = "".join(f"10:00:{t // 60:02d}:{t % 60:02d}.000,5,0.1,0.2,0,0,0\n" for t in range(600))
    cases["ARKit take .csv"].write_text(hr._LLF_HEADER.decode() + rows)
    cases["camera .json"].write_text(json.dumps({"width": 64, "height": 48, "fx": 80.0, "fy": 80.0, "cx": 32.0,
                                                 "cy": 24.0, "world_to_camera": np.eye(4).tolist()}, indent=40))
    return cases


def _flame_cases(d: Path, w: dict) -> dict[str, Path]:
    """The hostile FLAME pickles, and (once) the small GaussianAvatars folder they are given with."""
    from tests.support import ga_synthetic as gs

    if "ga" not in w:
        w["flame"] = gs.flame_arrays(1)
        w["ga"] = gs.write_ga_folder(w["root"] / "ga_out", 300, seed=2, frames=2, iterations=(30000,))
    return hr.flame_pickles(d, w["flame"])


def _flame_cli(argv: Callable[[Path, dict], list[str]]) -> dict:
    """A FLAME pickle given with a GaussianAvatars folder: also nothing run (no PWNED in the working folder) and
    nothing written (no --out file, no cached import, no config)."""
    return {**_cli(argv, env=lambda p: {"XDG_CACHE_HOME": str(p.parent / "cache"),
                                        "XDG_CONFIG_HOME": str(p.parent / "cfg")}),
            "unwritten": lambda p, w: [w["root"] / "PWNED", w["root"] / "ga.npga", p.parent / "cache",
                                       p.parent / "cfg"]}


READERS: dict[str, tuple[Callable[[Path, dict], dict[str, Path]], dict]] = {
    "expression codes .npy (export --expr)": (
        lambda d, w: hc.npy_codes(d, w["dim"]),
        _cli(lambda p, w: ["export", str(w["avatar"]), "--out", str(w["root"] / "o.ply"), "--expr", str(p)])),
    "sequence .npz/.npzseq (export --sequence)": (
        lambda d, w: hc.npz_sequences(d, w["dim"]),
        _cli(lambda p, w: ["export", str(w["avatar"]), "--out", str(w["root"] / "o.ply"), "--sequence", str(p),
                           "--frame", "0"])),
    "MonoNPHM tracking folder (export --sequence)": (
        lambda d, w: hc.mononphm_folders(d, w["dim"]),
        _cli(lambda p, w: ["export", str(w["avatar"]), "--out", str(w["root"] / "o.ply"), "--sequence", str(p),
                           "--frame", "0"])),
    "avatar .npga (info)": (
        lambda d, w: hc.npga_files(d, w["avatar"]),
        _cli(lambda p, w: ["info", str(p)])),
    "avatar .ply (info)": (
        lambda d, w: hc.ply_files(d, w["ply"]),
        _cli(lambda p, w: ["info", str(p)])),
    "camera JSON (render --camera)": (
        lambda d, w: hc.camera_json(d),
        _cli(lambda p, w: ["render", str(w["avatar"]), "--camera", str(p), "--out", str(w["root"] / "o.png")])),
    "rig camera_params.json (viewer --rig)": (
        lambda d, w: hc.rig_json(d),
        _cli(lambda p, w: ["view", str(w["avatar"]), "--rig", str(p), "--quit-after-frames", "1"])),
    "keyframe timeline JSON (render --timeline)": (
        lambda d, w: hc.keyframe_json(d, w["dim"]),
        _cli(lambda p, w: ["render", str(w["avatar"]), "--timeline", str(p), "--out", str(w["root"] / "o.mp4")])),
    "session JSON (viewer --session)": (
        lambda d, w: hc.session_json(d),
        _cli(lambda p, w: ["view", str(w["avatar"]), "--session", str(p), "--quit-after-frames", "1"])),
    "presets.json (viewer start)": (
        lambda d, w: hc.presets_configs(d),
        _cli(lambda p, w: ["view", str(w["avatar"]), "--quit-after-frames", "1"],
             env=lambda p: {"XDG_CONFIG_HOME": str(p)}, names=lambda p: [p / "npga-view" / "presets.json"])),
    "recent.json (viewer start)": (
        lambda d, w: hc.recent_configs(d),
        _cli(lambda p, w: ["view", str(w["avatar"]), "--quit-after-frames", "1"],
             env=lambda p: {"XDG_CONFIG_HOME": str(p)}, names=lambda p: [p / "npga-view" / "recent.json"])),
    "degenerate avatars (info)": (
        lambda d, w: hc.degenerate_avatars(d, w["ply"], w["avatar"], good_v2=w["v2"]),
        _accepted(lambda p, w: ["info", str(p)])),
    "degenerate avatars (export)": (
        lambda d, w: {k: v for k, v in hc.degenerate_avatars(d, w["ply"], w["avatar"]).items()
                      if "surrogates" not in k},  # export prints no names
        _accepted(lambda p, w: ["export", str(p), "--out", str(w["root"] / f"{p.stem}.ply")])),
    "bake cache .npgabake (pose worker)": (
        lambda d, w: hc.bake_caches(d, w["bake"]),
        _call("tests.support.hostile_corpus:open_bake_cache", lambda p, w: [str(p), w["key"]])),
    "preview cache .npz (pose worker)": (
        lambda d, w: hc.preview_caches(d, w["preview"]),
        _call("tests.support.hostile_corpus:load_preview_cache", lambda p, w: [str(p), w["key"], w["n"]])),
    # #25 ARKit takes
    "ARKit take .csv/.json (export --sequence)": (
        lambda d, w: hr.arkit_takes(d),
        _cli(lambda p, w: ["export", str(w["avatar"]), "--out", str(w["root"] / "o.ply"), "--sequence", str(p),
                           "--frame", "0"])),
    # the newer readers (#28 part 2)
    "GHA checkpoint folder (import gha)": (
        lambda d, w: hr.gha_folders(d, w["gha_head"], w["gha_supres"]),
        _cli(lambda p, w: ["import", "gha", str(p), "--out", str(w["root"] / "gha.npga")])),
    "GHA YAML config (import gha --config)": (
        lambda d, w: hr.gha_configs(d),
        _cli(lambda p, w: ["import", "gha", str(w["gha"]), "--config", str(p), "--out", str(w["root"] / "g.npga")])),
    "GHA params folder (import gha --sequence)": (
        lambda d, w: hr.gha_params(d, GHA_SMALL["exp_dim"]),
        _cli(lambda p, w: ["import", "gha", str(w["gha"]), "--sequence", str(p), "--out", str(w["root"] / "g.npga")])),
    "capture folder (evaluate's reader)": (
        lambda d, w: hr.captures(d),
        _partial("tests.support.hostile_readers_corpus:open_capture", lambda p, w: [str(p)])),
    # #37 the user's FLAME model (restricted unpickler) wherever a GaussianAvatars avatar opens
    "FLAME model pickle (import gaussian-avatars --flame-model)": (
        _flame_cases,
        _flame_cli(lambda p, w: ["import", "gaussian-avatars", str(w["ga"]), "--flame-model", str(p), "--out",
                                 str(w["root"] / "ga.npga")])),
    "FLAME model pickle (view FOLDER --flame-model)": (
        _flame_cases,
        _flame_cli(lambda p, w: ["view", str(w["ga"]), "--flame-model", str(p), "--quit-after-frames", "1"])),
    "files shrinking while read (info/export/render)": (
        _shrinking_files,
        {**_cli(lambda p, w: []), "call": "tests.support.hostile_readers_corpus:while_shrinking",
         "args": _shrinking_argv}),
}


def _check(name: str, target: Path, spec: dict, world: dict, folder: Path, env: dict | None = None) -> str | None:
    """Run one case; None when it behaved, else what went wrong."""
    out, err = folder / f"{target.name}.out", folder / f"{target.name}.err"
    req = {"stdout": str(out), "stderr": str(err), "limit_mb": LIMIT_MB, "timeout": TIMEOUT_S, "env": env or {}}
    if "call" in spec:
        req.update(call=spec["call"], args=spec["args"](target, world))
    else:
        req.update(argv=spec["argv"](target, world), env={**req["env"], **spec["env"](target)})
    reply = world["server"].run(req)
    text = err.read_text(errors="replace") if err.exists() else ""
    lines = [line for line in text.splitlines() if line.strip()]
    expected = spec["exit"](name) if callable(spec["exit"]) else spec["exit"]
    problems = []
    if reply["timed_out"]:
        problems.append(f"hung (killed after {TIMEOUT_S:g} s)")
    if reply["signal"] is not None:
        problems.append(f"died of signal {reply['signal']} (native crash)")
    if reply["exit"] != expected:
        problems.append(f"exit {reply['exit']}, expected {expected}")
    if "Traceback" in text:
        problems.append("traceback")
    if "argv" in spec and expected == 0 and "warning" in text.lower():
        problems.append("a warning")
    if callable(spec["exit"]) and expected == 0:  # partial: problems on stdout, each naming a file; stderr empty
        said = [line for line in out.read_text(errors="replace").splitlines() if line.startswith("problem: ")]
        if lines or not said or not all(str(target) in line for line in said):
            problems.append(f"stderr {len(lines)} lines, {len(said)} problem lines not all naming a file")
    if expected == 2:
        if len(lines) != 1:
            problems.append(f"{len(lines)} lines on stderr")
        elif not any(str(n) in lines[0] for n in spec["names"](target)):
            problems.append("the message does not name the file")
    if (folder / hc.MARKER).exists():
        problems.append("UNPICKLED")
    written = [str(p) for p in spec.get("unwritten", lambda p, w: [])(target, world) if os.path.lexists(p)]
    if written:
        problems.append(f"wrote {', '.join(written)}")
    return f"{name}: {'; '.join(problems)} | {text.strip()[-300:]!r}" if problems else None


@pytest.mark.slow
@pytest.mark.parametrize("reader", list(READERS))
def test_hostile_corpus(reader, world, tmp_path):
    build, spec = READERS[reader]
    folder = tmp_path / "corpus"
    folder.mkdir()
    cases = build(folder, world)
    failures = [f for name, target in cases.items() if (f := _check(name, target, spec, world, folder))]
    print(f"\n{reader}: {len(cases)} hostile cases, {len(cases) - len(failures)} handled")
    assert len(cases) >= (6 if "shrinking" in reader else 10 if spec["exit"] != 0 or "call" in spec else 3)
    assert not failures, "\n".join(failures)


def test_autosave_recovery_refuses_hostile_autosaves(world, tmp_path, monkeypatch):
    """The Edit panel's Recover reads the autosave of the open avatar: every hostile .npga (and FIFO, directory,
    device) placed there is refused with one line naming it (or, for what is not a regular file, "no autosave")."""
    from npga_core.editing.edits import autosave_path_for

    source = tmp_path / "edited.npga"
    source.write_bytes(world["avatar"].read_bytes())
    corpus_dir = tmp_path / "corpus"
    corpus_dir.mkdir()
    corpus = {k: v for k, v in hc.npga_files(corpus_dir, world["avatar"]).items() if k != "missing"}
    failures = []
    for i, (name, case) in enumerate(corpus.items()):
        home = tmp_path / f"cache{i}"
        monkeypatch.setenv("XDG_CACHE_HOME", str(home))
        target = autosave_path_for(source)  # where the viewer autosaves edits of `source`
        target.parent.mkdir(parents=True)
        if case.is_symlink():
            target.symlink_to(os.readlink(case))
        else:
            case.rename(target)
        spec = {"call": "tests.support.hostile_corpus:recover_autosave", "args": lambda p, w: [str(source)], "exit": 2,
                "names": lambda p: [p, source]}
        failure = _check(name, target, spec, world, corpus_dir, env={"XDG_CACHE_HOME": str(home)})
        if failure:
            failures.append(failure)
    print(f"\nautosave .npga (Edit panel Recover): {len(corpus)} hostile cases, {len(corpus) - len(failures)} handled")
    assert len(corpus) >= 10
    assert not failures, "\n".join(failures)


# -- the real console entry point ---------------------------------------------------------------------------------
def _limit_address_space() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))  # far below what the hostile headers claim


@pytest.mark.parametrize("kind", ["npy huge shape", "fifo avatar"])
def test_console_entry_point(kind, world, tmp_path):
    """Cases of the issue through `python -m npga_view.cli` in a fresh process with RLIMIT_AS set in preexec_fn
    (the rest of the corpus runs `main` in forked children; deep keyframes and a huge camera are its cases too):
    exit 2, one line naming the file, no traceback, no hang."""
    avatar = str(world["avatar"])
    if kind == "npy huge shape":
        p = tmp_path / "huge.npy"
        p.write_bytes(hc.npy_header((10**9, 10**6)))
        argv = ["export", avatar, "--out", str(tmp_path / "o.ply"), "--expr", str(p)]
    else:
        p = tmp_path / "fifo.npga"
        os.mkfifo(p)
        argv = ["info", str(p)]
    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "npga_view.cli", *argv], capture_output=True, text=True,
                       timeout=300, preexec_fn=_limit_address_space, cwd=root,
                       env={**os.environ, "PYTHONPATH": str(root), "DISPLAY": ""})
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.count("\n") == 1 and str(p) in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("budget", ["0", "nan", "inf", "-1", "1e-9", "1e308"])
def test_hostile_bake_budget_is_one_line(budget, world, tmp_path):
    """`view --bake --bake-budget-mb B` with a budget no bake can use (0 made the viewer wait for a bake
    forever; NaN passed the `<= 0` check): exit 2, one line naming the option, before any window."""
    seq = tmp_path / "seq.npy"
    np.save(seq, np.zeros((4, world["dim"]), np.float32))
    err = tmp_path / "err"
    reply = world["server"].run({"argv": ["view", str(world["avatar"]), "--sequence", str(seq), "--bake",
                                          "--bake-budget-mb", budget, "--quit-after-frames", "1"],
                                 "stdout": str(tmp_path / "out"), "stderr": str(err), "limit_mb": LIMIT_MB,
                                 "timeout": TIMEOUT_S, "env": {}})
    text = err.read_text()
    assert not reply["timed_out"] and reply["signal"] is None and reply["exit"] == 2, text
    assert len(text.strip().splitlines()) == 1 and "--bake-budget-mb" in text and "Traceback" not in text, text


def test_hostile_udp_packets_are_counted_bad():
    """Live Link Face datagrams a broken or hostile sender may send (truncated, huge or negative subject lengths,
    NaN/Inf/3e38 values, NaN sub-frames, rates of 0 or 10^9, wrong value counts, undecodable subjects, noise):
    `decode` raises PacketError and nothing else, and the receiver counts them as bad without taking one."""
    from npga_core.posing.livelink import LiveLinkReceiver, PacketError, decode

    packets = hr.udp_packets()
    taken = []
    for name, data in packets.items():
        try:
            decode(data)
            taken.append(name)
        except PacketError:
            pass
    assert not taken, taken
    with LiveLinkReceiver(port=0) as receiver:  # a free loopback port; fed directly
        assert not any(receiver.feed(data) for data in packets.values())
        assert receiver.counters.bad == len(packets) >= 20 and receiver.latest() is None
