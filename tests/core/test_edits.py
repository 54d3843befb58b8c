"""EditSession: commands undo bit-exactly, deletions stay consistent, saving is safe, autosave recovers."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from npga_core.editing.edits import (
    DeleteSelected,
    EditSession,
    Hide,
    NothingSelectedError,
    RemoveFloaters,
    ScaleFeature,
    ScaleOpacity,
    SetFeature,
    ShowAll,
    SourceOverwriteError,
    Tint,
    find_autosave,
    floater_mask,
)
from npga_core.files.checkpoint import save_avatar
from npga_core.files.loading import load_avatar
from npga_core.model.gaussians import PER_GAUSSIAN_FIELDS, SH_C0, logit, sigmoid
from npga_core.model.synthetic import make_synthetic_avatar
from tests.support.panels import PanelDriver

REPO = Path(__file__).resolve().parents[2]


def small(n: int = 300, seed: int = 1):
    return make_synthetic_avatar(n, hidden=32, depth=2, code_dim=12, n_components=6, latent_dim=2, seed=seed)


@pytest.fixture(autouse=True)
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def snapshot(s: EditSession) -> dict[str, np.ndarray]:
    snap = {k: np.array(v) for k, v in s.avatar.cloud.arrays().items()}
    snap["_selection"], snap["_hidden"] = s.selection.copy(), s.hidden.copy()
    return snap


def assert_bit_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert a[k].tobytes() == b[k].tobytes(), f"{k} differs"


def selected_session(n: int = 300) -> EditSession:
    s = EditSession(small(n))
    rng = np.random.default_rng(5)
    s.select(rng.random(n) < 0.3)
    return s


COMMANDS = {
    "delete": DeleteSelected,
    "hide": Hide,
    "scale_opacity": lambda: ScaleOpacity(0.3),
    "tint_multiply": lambda: Tint((1.0, 0.2, 0.5), "multiply"),
    "tint_blend": lambda: Tint((0.1, 0.9, 0.1), "blend", 0.7),
    "set_feature": lambda: SetFeature(2, 0.25),
    "scale_feature": lambda: ScaleFeature(0, -2.0),
    "floaters": lambda: RemoveFloaters(k=6, distance_factor=1.5, min_opacity=0.7),
}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_each_command_undoes_and_redoes_bit_exactly(name):
    s = selected_session()
    s.run(Hide())  # a hidden mask that deletion has to carry along
    s.select(np.random.default_rng(6).random(len(s)) < 0.3)
    before = snapshot(s)
    s.run(COMMANDS[name]())
    after = snapshot(s)
    assert any(after[k].shape != before[k].shape or after[k].tobytes() != before[k].tobytes() for k in before)
    s.undo()
    assert_bit_equal(snapshot(s), before)
    s.redo()
    assert_bit_equal(snapshot(s), after)
    s.undo()
    assert_bit_equal(snapshot(s), before)


def test_a_mixed_history_unwinds_to_the_original():
    s = selected_session()
    original = snapshot(s)
    states = []
    for cmd in (Tint((0.5, 0.5, 1.0)), DeleteSelected(), ScaleOpacity(2.0), SetFeature(1, -1.0)):
        if not s.selection.any():
            s.select(np.arange(len(s)) % 3 == 0)
        s.run(cmd)
        states.append(snapshot(s))
    names, redo = s.history.names()
    assert names == ["Select (89)", "Tint multiply (0.50, 0.50, 1.00)", "Delete 89", "Select (71)",
                     "Scale opacity x2", "Set feature 1 = -1"]
    assert redo == []
    while len(s.history.undo_stack) > 1:  # back to just the first selection
        s.undo()
    assert_bit_equal(snapshot(s), original)
    assert not s.dirty
    assert s.history.names() == (names[:1], names[1:])
    while s.can_redo:
        s.redo()
    assert_bit_equal(snapshot(s), states[-1])
    assert s.dirty


def test_delete_keeps_every_array_consistent_and_the_model_unchanged():
    s = selected_session()
    a = s.avatar
    dyn, ex, cnn = a.dynamics, a.expression, a.cnn
    full = snapshot(s)
    sel = s.selection.copy()
    s.run(DeleteSelected())
    keep = ~sel
    assert len(a) == keep.sum() == len(s.selection) == len(s.hidden)
    for name in PER_GAUSSIAN_FIELDS:
        arr = getattr(a.cloud, name)
        if full.get(name) is None:  # an optional array this avatar does not have stays absent
            assert arr is None, name
            continue
        assert arr is not None and arr.shape[0] == keep.sum(), name
        np.testing.assert_array_equal(arr, full[name][keep])
    assert a.dynamics is dyn and a.expression is ex and a.cnn is cnn
    assert a.cloud.part_names == ["face", "back_head", "neck"]
    assert not s.selection.any()


def test_edits_never_write_the_loaded_arrays(tmp_path):
    path = tmp_path / "a.npga"
    save_avatar(small(), path)
    raw = path.read_bytes()
    avatar = load_avatar(path)
    assert not avatar.cloud.opacity_logits.flags.writeable  # memory-mapped, read-only
    s = EditSession(avatar)
    s.select_all()
    s.run(ScaleOpacity(0.5))
    s.run(Tint((1, 0, 0)))
    s.undo()
    s.undo()
    assert path.read_bytes() == raw
    np.testing.assert_array_equal(s.avatar.cloud.opacity_logits, load_avatar(path).cloud.opacity_logits)


def test_operation_values():
    s = selected_session()
    idx = np.flatnonzero(s.selection)
    rest = np.flatnonzero(~s.selection)
    op0, sh0, f0 = sigmoid(s.avatar.cloud.opacity_logits), np.array(s.avatar.cloud.sh), np.array(
        s.avatar.cloud.features)
    s.run(ScaleOpacity(0.5))
    op = sigmoid(s.avatar.cloud.opacity_logits)
    np.testing.assert_allclose(op[idx], 0.5 * op0[idx], rtol=1e-5)
    np.testing.assert_array_equal(op[rest], op0[rest])
    s.run(ScaleOpacity(100.0))  # clamped into (0, 1), stored as finite logits
    assert np.all(np.isfinite(s.avatar.cloud.opacity_logits)) and np.all(sigmoid(s.avatar.cloud.opacity_logits) <= 1)
    np.testing.assert_allclose(s.avatar.cloud.opacity_logits[idx], logit(np.ones(1))[0])
    s.run(Tint((1.0, 0.0, 0.5)))
    rgb0, rgb = sh0[:, 0] * SH_C0 + 0.5, s.avatar.cloud.sh[:, 0] * SH_C0 + 0.5
    np.testing.assert_allclose(rgb[idx], rgb0[idx] * [1.0, 0.0, 0.5], atol=1e-6)
    np.testing.assert_array_equal(s.avatar.cloud.sh[:, 1:], sh0[:, 1:])  # view-dependent terms stay
    s.run(Tint((0.0, 1.0, 0.0), "blend", 1.0))
    np.testing.assert_allclose(s.avatar.cloud.sh[idx, 0] * SH_C0 + 0.5, np.tile([0, 1, 0], (len(idx), 1)), atol=1e-6)
    s.run(SetFeature(3, 0.75))
    s.run(ScaleFeature(4, 3.0))
    f = s.avatar.cloud.features
    assert np.all(f[idx, 3] == np.float32(0.75))
    np.testing.assert_allclose(f[idx, 4], 3.0 * f0[idx, 4], rtol=1e-6)
    np.testing.assert_array_equal(f[rest], f0[rest])
    with pytest.raises(ValueError, match="feature channel 8"):
        s.run(SetFeature(8, 0.0))
    for bad in (lambda: ScaleOpacity(-1), lambda: Tint((1, 1, 1), "screen"), lambda: SetFeature(0, np.nan)):
        with pytest.raises(ValueError):
            bad()


def test_operations_need_a_selection():
    s = EditSession(small())
    for cmd in (DeleteSelected(), Hide(), ScaleOpacity(0.5), Tint((1, 0, 0))):
        with pytest.raises(NothingSelectedError):
            s.run(cmd)
    assert not s.can_undo and s.version == 0


def test_selection_is_undoable_and_not_dirty():
    s = EditSession(small())
    s.avatar.pose()  # fills the caches
    cached = s.avatar.canonical_tensors()
    a = np.arange(len(s)) < 50
    assert s.select(a)
    assert not s.select(a)  # no change, no step
    s.select(np.arange(len(s)) >= 280, "add")
    assert s.selection.sum() == 70
    assert s.version == 0 and s.mask_version == 2 and not s.dirty
    assert s.avatar.canonical_tensors() is cached  # selections leave the pose caches alone
    s.undo()
    np.testing.assert_array_equal(s.selection, a)
    s.invert()
    assert s.selection.sum() == len(s) - 50
    s.clear_selection()
    assert not s.selection.any()
    s.grow()  # nothing to grow from
    s.select(np.arange(len(s)) == 7)
    s.grow(1, k=4)
    assert 2 <= s.selection.sum() <= 9 and s.selection[7]
    s.shrink(1, k=4)
    assert s.selection[7] and s.selection.sum() == 1
    # hidden Gaussians cannot be selected
    s.select(np.arange(len(s)) < 10)
    s.run(Hide())
    assert s.hidden.sum() == 10 and not s.selection.any()
    s.select_all()
    assert s.selection.sum() == len(s) - 10
    s.run(ShowAll())
    assert not s.hidden.any()
    # cloud edits invalidate the caches and bump the version
    s.run(ScaleOpacity(0.9))
    assert s.version == 1 and s.dirty and s.avatar.canonical_tensors() is not cached


def test_screen_and_range_selection_through_the_session():
    from npga_core.camera.cameras import frame_points

    s = EditSession(small())
    cam = frame_points(s.avatar.cloud.means, 200, 300)
    posed = s.avatar.pose()
    assert s.select_rect(cam, 0, 0, 100, 300, means=posed.means)
    left = s.selection.copy()
    assert 0 < left.sum() < len(s)
    assert s.select_rect(cam, 100, 0, 200, 300, mode="add", means=posed.means)
    assert s.selection.all() or s.selection.sum() > left.sum()
    s.clear_selection()
    s.select_brush(cam, [[100, 150], [110, 150]], 20.0, means=posed.means)
    assert s.selection.any()
    s.select_lasso(cam, [[0, 0], [200, 0], [200, 300]], mode="subtract", means=posed.means)
    s.select_sphere([0, 0, 0], 0.5)
    assert s.selection.all()
    s.select_box([-1, -1, 0], [1, 1, 1])
    np.testing.assert_array_equal(s.selection, s.avatar.cloud.means[:, 2] >= 0)
    s.select_range("opacity", 0.0, 0.8)
    np.testing.assert_array_equal(s.selection, sigmoid(s.avatar.cloud.opacity_logits) <= 0.8)


def _with_floaters():
    avatar = small(400)
    c = avatar.cloud
    far = np.arange(5)
    c.means[far] = c.means[far] * 4.0  # well outside the head shell
    faint = np.arange(10, 14)
    c.opacity_logits[faint] = logit(np.full(4, 0.005))
    return avatar, set(far) | set(faint)


def test_floater_mask_and_removal():
    avatar, expected = _with_floaters()
    assert set(np.flatnonzero(floater_mask(avatar.cloud, k=8, distance_factor=3.0, min_opacity=0.02))) == expected
    s = EditSession(avatar)
    assert s.preview_floaters(k=8) == len(expected)
    assert set(np.flatnonzero(s.preview)) == expected
    before = snapshot(s)
    s.run(RemoveFloaters(k=8))
    assert len(s) == 400 - len(expected) and s.preview is None
    assert s.history.names()[0][-1] == f"Remove {len(expected)} floaters"
    assert not floater_mask(s.avatar.cloud).any()
    s.undo()
    assert_bit_equal(snapshot(s), before)
    s.select(np.arange(400) < 3)
    s.run(RemoveFloaters(k=8, within_selection=True))
    assert len(s) == 397


def test_save_load_after_deletions_poses_the_same(tmp_path):
    src = tmp_path / "src.npga"
    save_avatar(small(), src)
    s = EditSession(load_avatar(src))
    s.select(np.arange(len(s)) % 4 == 1)
    s.run(DeleteSelected())
    s.select(np.arange(len(s)) < 30)
    s.run(Tint((0.2, 0.4, 1.0)))
    s.run(DeleteSelected())
    out = tmp_path / "edited.npga"
    assert s.save(out) == out
    assert not s.dirty
    back = load_avatar(out)
    assert len(back) == len(s.avatar) == 300 - 75 - 30
    for name in PER_GAUSSIAN_FIELDS:
        np.testing.assert_array_equal(getattr(back.cloud, name), getattr(s.avatar.cloud, name))
    z = back.expression.sample(np.random.default_rng(0))
    p0, p1 = s.avatar.pose(z), back.pose(z)
    for f in ("means", "quats", "scales", "opacities", "sh", "latent"):
        np.testing.assert_array_equal(getattr(p0, f), getattr(p1, f))
    np.testing.assert_array_equal(back.expression.mean, s.avatar.expression.mean)
    assert back.provenance["edited_from"] == str(src)
    assert back.provenance["edits"] == ["Delete 75", "Tint multiply (0.20, 0.40, 1.00)", "Delete 30"]


def test_the_source_is_not_overwritten_without_asking(tmp_path):
    src = tmp_path / "src.npga"
    save_avatar(small(), src)
    raw = src.read_bytes()
    s = EditSession(load_avatar(src))
    s.select(np.arange(len(s)) < 20)
    s.run(DeleteSelected())
    assert s.dirty
    for call in (lambda: s.save(), lambda: s.save(str(src)), lambda: s.save(tmp_path / "." / "src.npga")):
        with pytest.raises(SourceOverwriteError, match="overwrite"):
            call()
    assert src.read_bytes() == raw and s.dirty
    other = tmp_path / "copy.npga"
    s.save(other)  # "Save as": later "Save"s go there without asking
    s.select(np.arange(len(s)) < 5)
    s.run(DeleteSelected())
    assert s.dirty
    s.save()
    assert len(load_avatar(other)) == 275 and not s.dirty
    s.save(src, overwrite_source=True)
    assert len(load_avatar(src)) == 275
    s.undo()
    assert s.dirty
    s.redo()
    assert not s.dirty
    with pytest.raises(ValueError, match="Save as"):
        EditSession(small()).save()


def test_autosave_and_recovery(tmp_path):
    src = tmp_path / "src.npga"
    save_avatar(small(), src)
    s = EditSession(load_avatar(src))
    assert s.autosave() is None  # nothing unsaved
    s.select(np.arange(len(s)) < 40)
    s.run(DeleteSelected())
    path = s.autosave()
    assert path is not None and path.is_file()
    assert path.parent == tmp_path / "cache" / "npga-view" / "autosave"
    assert find_autosave(src) == path
    r = EditSession.recover(src)
    assert r.source == str(src) and r.dirty and len(r) == 260
    np.testing.assert_array_equal(r.avatar.cloud.means, s.avatar.cloud.means)
    with pytest.raises(SourceOverwriteError):
        r.save()
    os.utime(src, (time.time() + 100, time.time() + 100))  # the source changed after the autosave: stale
    assert find_autosave(src) is None
    os.utime(src, (time.time() - 100, time.time() - 100))
    s.save(tmp_path / "saved.npga")
    assert not path.exists() and find_autosave(src) is None
    with pytest.raises(FileNotFoundError):
        EditSession.recover(src)


SLOW_SAVE = textwrap.dedent("""
    import os, sys, time
    import numpy as np
    from npga_core.files.loading import load_avatar
    from npga_core.editing.edits import DeleteSelected, EditSession

    real_fdopen = os.fdopen

    class SlowFile:
        # a file whose writes trickle out in 4 KiB pieces, announcing the first one
        def __init__(self, fh):
            self.fh, self.started = fh, False
        def write(self, data):
            view = memoryview(data).cast("B")
            for i in range(0, len(view), 4096):
                self.fh.write(view[i:i + 4096])
                if not self.started:
                    self.fh.flush()
                    self.started = True
                    print("writing", flush=True)
                time.sleep(0.2)
        def __getattr__(self, name):
            return getattr(self.fh, name)
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self.fh.__exit__(*exc)

    os.fdopen = lambda *a, **k: SlowFile(real_fdopen(*a, **k))
    s = EditSession(load_avatar(sys.argv[1]))
    s.select(np.arange(len(s)) < 100)
    s.run(DeleteSelected())
    s.save(overwrite_source=True)
    print("finished", flush=True)
""")


@pytest.mark.slow
def test_a_killed_save_leaves_the_old_file_intact(tmp_path):
    src = tmp_path / "avatar.npga"
    save_avatar(small(2000), src)
    raw = src.read_bytes()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-c", SLOW_SAVE, str(src)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    try:
        line = proc.stdout.readline()
        assert line.strip() == "writing", proc.stderr.read()
        temps = list(tmp_path.glob(".avatar.npga.*.tmp"))
        assert len(temps) == 1 and 0 < temps[0].stat().st_size < len(raw)  # caught mid-write
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    assert src.read_bytes() == raw
    back = load_avatar(src)
    assert len(back) == 2000
    np.testing.assert_array_equal(back.cloud.means, load_avatar(src).cloud.means)


def test_export_posed_ply_leaves_out_hidden(tmp_path):
    from npga_core.files.ply import read_ply

    s = EditSession(small())
    s.select(np.arange(len(s)) < 25)
    s.run(Hide())
    assert s.export_posed_ply(tmp_path / "v.ply") == 275
    assert len(read_ply(tmp_path / "v.ply")) == 275
    assert s.export_posed_ply(tmp_path / "all.ply", include_hidden=True) == 300


# --------------------------------------------------------------------------------------------------
# the Edit panel, drawn in a headless imgui context and clicked like a user


def test_edit_panel_emits_actions_that_apply_carries_out():
    from npga_view import actions as A
    from npga_view.controllers.edit_actions import apply_edit
    from npga_view.panels.edit import EditPanel
    from npga_view.panels.info import AppInfo
    from npga_view.state import ViewerState

    s = EditSession(small())
    info, state = AppInfo(avatar=s.avatar), ViewerState()
    info.edit = s
    driver = PanelDriver(EditPanel(), state, info)
    try:
        assert {"edit_delete", "edit_undo", "edit_tool_brush"} <= set(info.rects)
        driver.click("edit_tool_brush")
        assert state.actions == [A.SelectTool("brush", "replace", 20.0)]
        state.actions.clear()
        driver.click("edit_delete")  # disabled: nothing selected
        assert state.actions == []
        s.select(np.arange(len(s)) < 30)
        driver.frame()
        driver.click("edit_delete")
        assert state.actions == [A.DeleteSelection()]
        for action in state.actions:
            assert apply_edit(s, action)
        state.actions.clear()
        assert len(s) == 270
        driver.frame()
        driver.click("edit_undo")
        assert state.actions == [A.Undo()]
        assert apply_edit(s, A.Undo()) and len(s) == 300
    finally:
        driver.close()


def test_apply_covers_the_panel_actions(tmp_path):
    from npga_core.camera.cameras import frame_points
    from npga_view import actions as A
    from npga_view.controllers.edit_actions import EditView, apply_edit

    s = EditSession(small())
    cam = frame_points(s.avatar.cloud.means, 100, 150)
    posed = s.avatar.pose()
    steps = [
        A.SelectRect((0, 0, 50, 150), "replace"),
        A.SelectLasso(((0, 0), (100, 0), (100, 150)), "add"),
        A.SelectBrush(((50, 75),), 10.0, "subtract"),
        A.SelectSphere((0, 0, 0), 0.2, "intersect"),
        A.SelectBox((-1, -1, 0), (1, 1, 1), "replace"),
        A.SelectRange("opacity", 0.0, 0.9, "intersect"),
        A.SelectGrow(1), A.SelectShrink(1), A.SelectInvert(), A.SelectAll(),
        A.ScaleSelectionOpacity(0.5), A.TintSelection((1, 0, 0), "blend", 0.5),
        A.SetSelectionFeature(0, 1.0), A.ScaleSelectionFeature(1, 2.0),
        A.HideSelection(), A.ShowAllHidden(), A.SelectClear(),
        A.PreviewFloaters(8, 1.2, 0.0),
        A.ClearFloaterPreview(),
        A.RemoveFloaters(8, 1.2, 0.0, within_selection=False),
        A.Undo(), A.Redo(),
        A.SaveEdits(str(tmp_path / "e.npga"), False),
        A.ExportPly(str(tmp_path / "e.ply")),
    ]
    for action in steps:
        assert apply_edit(s, action, EditView(cam, posed.means)), action
    assert not apply_edit(s, A.SelectTool("rect")) and not apply_edit(s, A.OpenAvatar("x"))
    with pytest.raises(A.ActionError, match="SelectSphere.radius"):
        apply_edit(s, A.SelectSphere((0, 0, 0), "big"))  # a field of the wrong type is an error, not a no-op
    names = [c.name for c in s.history.undo_stack]
    assert names[-4:-1] == ["Scale feature 1 x2", "Hide 300", "Show all"]  # hide deselected: clear was no step
    assert names[-1].startswith("Remove ") and len(s) < 300
    assert len(load_avatar(tmp_path / "e.npga")) == len(s) and (tmp_path / "e.ply").is_file()
    with pytest.raises(ValueError, match="camera"):
        apply_edit(s, A.SelectRect((0, 0, 1, 1)))


def test_a_deletion_says_which_rows_it_kept_and_their_pose_is_the_edited_clouds():
    s = EditSession(small())
    z = s.avatar.expression.sample(np.random.default_rng(4))
    before = s.avatar.pose(z)
    s.select(np.arange(len(s)) % 4 == 1)
    s.run(DeleteSelected())
    version_before, kept = s.kept_rows
    assert version_before == s.version - 1 and kept.shape == (300,) and kept.sum() == len(s) == 225
    after = s.avatar.pose(z)  # every Gaussian's dynamics are its own: the kept rows' pose is unchanged
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_allclose(getattr(after, name), getattr(before, name)[kept], rtol=1e-5, atol=1e-6)
    s.undo()
    assert s.kept_rows is None  # rows came back: they must be posed
    s.redo()
    assert s.kept_rows is not None and np.array_equal(s.kept_rows[1], kept)
    s.select_all()
    s.run(ScaleOpacity(0.5))
    assert s.kept_rows is None  # an attribute changed
