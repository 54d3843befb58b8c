"""The pose worker process: results equal the in-process pose; newest request wins; errors reported."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.checkpoint import read_avatar
from npga_core.posing.engine import PoseEngine


def _engine(path):
    a = read_avatar(path)
    return a, PoseEngine(str(path), len(a.cloud), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1)


@pytest.mark.slow
def test_worker_result_equals_in_process_pose(small_npga):
    a, eng = _engine(small_npga)
    with eng:
        z = a.expression.sample(np.random.default_rng(0))
        eng.request(z)
        r = eng.wait()
        assert r is not None and np.array_equal(r.code, z)
        ref = a.pose(z)
        for name in ("means", "quats", "scales", "opacities", "sh", "latent"):
            np.testing.assert_allclose(getattr(r.posed, name), getattr(ref, name), rtol=1e-5, atol=1e-7)
        assert {"F", "G", "pose_total"} <= set(r.timings)
        r.release()


@pytest.mark.slow
def test_newest_request_wins(small_npga):
    a, eng = _engine(small_npga)
    with eng:
        rng = np.random.default_rng(1)
        codes = [a.expression.sample(rng) for _ in range(20)]
        ids = [eng.request(z) for z in codes]
        r = eng.wait()
        assert r.request_id == ids[-1] and np.array_equal(r.code, codes[-1])
        r.release()


@pytest.mark.slow
def test_wrong_dimension_reported_not_fatal(small_npga):
    a, eng = _engine(small_npga)
    with eng:
        eng.request(np.zeros(7, np.float32))
        assert eng.wait(timeout=30) is None and "7 dims" in eng.last_error
        eng.request(a.neutral_code())
        r = eng.wait()
        assert r is not None and eng.alive
        r.release()


def _shm_exists(name: str) -> bool:
    from multiprocessing import shared_memory

    try:
        shared_memory.SharedMemory(name=name).close()
    except FileNotFoundError:
        return False
    return True


@pytest.mark.slow
def test_close_twice_and_dropping_an_engine_stop_the_worker(small_npga):
    """close() is idempotent; an engine dropped without close() still stops its worker and unlinks its slots
    (weakref.finalize, also run at interpreter exit)."""
    import gc
    import time

    a, eng = _engine(small_npga)
    eng.request(a.neutral_code())
    eng.wait().release()
    names, proc = eng.shm_names, eng.process
    eng.close()
    eng.close()
    assert not proc.is_alive() and not any(_shm_exists(n) for n in names)

    a, eng = _engine(small_npga)
    eng.request(a.neutral_code())
    eng.wait().release()
    names, proc = eng.shm_names, eng.process
    del eng
    gc.collect()
    end = time.monotonic() + 60  # a bound on waiting, not a speed
    while proc.is_alive() and time.monotonic() < end:
        time.sleep(0.05)
    assert not proc.is_alive() and not any(_shm_exists(n) for n in names)


@pytest.mark.slow
def test_a_replaced_worker_stops_in_the_background(small_npga):
    """close(wait=False) (a worker replaced after an edit or by another avatar) returns at once; the worker still
    stops and its slots are unlinked, and `wait_for_shutdowns` (run at interpreter exit) waits for that."""
    from npga_core.posing.lifetime import wait_for_shutdowns

    a, eng = _engine(small_npga)
    eng.request(a.neutral_code())
    eng.wait().release()
    names, proc = eng.shm_names, eng.process
    eng.request(a.expression.sample(np.random.default_rng(1)))  # (a job under way)
    eng.close(wait=False)
    eng.close()  # idempotent after a background close too
    wait_for_shutdowns(timeout_s=60)  # a bound on waiting, not a speed
    assert not proc.is_alive() and not any(_shm_exists(n) for n in names)


@pytest.mark.slow
def test_a_worker_replaced_while_it_starts_stops_cleanly(small_npga, capfd):
    """An engine closed in the background before its worker has started (an edit right after opening): the
    worker still starts from what it was handed, stops, and prints nothing (its queues' semaphores were once
    freed with the engine, and the starting worker died in a traceback)."""
    import gc

    from npga_core.posing.lifetime import wait_for_shutdowns

    procs = []
    for _ in range(3):
        _, eng = _engine(small_npga)
        procs.append((eng.process, eng.shm_names))
        eng.close(wait=False)
        del eng
        gc.collect()
    wait_for_shutdowns(timeout_s=120)  # a bound on waiting, not a speed
    err = capfd.readouterr().err
    assert "Traceback" not in err, err[-2000:]
    for proc, names in procs:  # (stopped when asked, or killed 5 s after: three starting at once on a busy machine)
        assert not proc.is_alive() and proc.exitcode in (0, -9) and not any(_shm_exists(n) for n in names)


@pytest.mark.slow
def test_an_edited_cloud_is_reopened_in_the_running_worker(small_npga, tmp_path):
    from npga_core.editing.commands import DeleteSelected
    from npga_core.editing.edits import EditSession
    from npga_core.files.checkpoint import save_avatar

    a, eng = _engine(small_npga)
    k, h, n0 = a.cloud.sh.shape[1], a.cloud.latent_dim, len(a)
    with eng:
        z = a.expression.sample(np.random.default_rng(3))
        before = a.pose(z)  # (the session edits `a` itself)
        eng.request(z)
        eng.wait(exact=True).release()
        pid = eng.pid
        eng.bake(np.stack([z, -z]))
        s = EditSession(a)
        s.select(np.arange(len(a)) % 3 == 0)
        s.run(DeleteSelected())
        save_avatar(s.avatar, tmp_path / "deleted.npga")
        old = eng.request(0.5 * z)  # before the reopen: dropped, never answered with the old file's rows
        assert eng.reopen(str(tmp_path / "deleted.npga"), len(s.avatar), k, h)
        assert eng.bake_status is None and eng.pending is None
        new = eng.request(z)
        r = eng.wait(exact=True)
        assert r is not None and r.request_id == new > old and eng.pid == pid and eng.status["reopened"] > 0
        ref = s.avatar.pose(z)
        assert len(r.posed) == len(ref) < n0
        np.testing.assert_allclose(r.posed.means, ref.means, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(r.posed.sh, ref.sh, rtol=1e-5, atol=1e-6)
        r.release()
        s.undo()  # back to every row: still fits the slots
        save_avatar(s.avatar, tmp_path / "undone.npga")
        assert eng.reopen(str(tmp_path / "undone.npga"), len(s.avatar), k, h)
        eng.request(z)
        r = eng.wait(exact=True)
        assert len(r.posed) == n0
        np.testing.assert_allclose(r.posed.means, before.means, rtol=1e-5, atol=1e-7)
        r.release()
        assert not eng.reopen(str(tmp_path / "undone.npga"), n0 + 1, k, h)  # outgrows the slots: a new engine
        assert eng.pid == pid and eng.alive
