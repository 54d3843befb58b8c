"""The open-avatar document (npga_view/document.py): typed subscriptions, its events, and every part that
subscribes resetting what it held of the last avatar when another one opens (built headless, as the app builds
them; the list of subscribers is read from the code, so a new one cannot be left out of this test)."""

from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from npga_core.camera.orbit import OrbitCamera
from npga_core.editing.edits import DeleteSelected
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.document import AvatarOpened, CloudChanged, Document, SequenceChanged, Subscriptions
from npga_view.state import ViewerState

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"hidden": 64, "depth": 3}  # networks small enough to pose in-process at once


def test_handlers_run_by_event_type_in_the_order_included():
    doc, seen = Document(), []
    first, second = Subscriptions(), Subscriptions()
    first.subscribe(AvatarOpened, lambda e: seen.append(("first", type(e).__name__)))
    second.subscribe(AvatarOpened, lambda e: seen.append(("second", type(e).__name__)))
    second.subscribe(CloudChanged, lambda e: seen.append(("second", type(e).__name__)))
    second.subscribe(SequenceChanged, lambda e: seen.append(("second", e.sequence and e.sequence.name)))
    doc.include(first)
    doc.include(second)
    avatar = make_synthetic_avatar(50, seed=1, **SMALL)  # (in memory: no file, so no worker)
    doc.posed, doc.code = avatar.pose(), np.zeros(3, np.float32)
    doc.open(avatar)
    assert seen == [("first", "AvatarOpened"), ("second", "AvatarOpened")]
    assert doc.avatar is avatar and doc.engine is None and doc.posed is None and doc.code is None
    doc.change_cloud(None)
    assert seen[-1] == ("second", "CloudChanged")
    seq = ExpressionSequence(np.zeros((4, avatar.code_dim), np.float32), 25.0, "still")
    doc.set_sequence(seq)
    doc.set_sequence(None)
    assert seen[-2:] == [("second", "still"), ("second", None)] and doc.sequence is None
    assert len(doc.handlers(AvatarOpened)) == 2
    assert doc.handlers(SequenceChanged) == tuple(second.table[SequenceChanged])


def test_shown_clouds_count_versions_and_give_their_means():
    doc = Document()
    avatar = make_synthetic_avatar(40, seed=2, **SMALL)
    doc.open(avatar)
    np.testing.assert_array_equal(doc.shown_means(), avatar.cloud.means)  # the canonical cloud until a pose
    posed = avatar.pose()
    posed.means = posed.means + 1.0
    v0 = doc.version
    assert doc.shown(posed, None) == v0 + 1 and doc.posed is posed
    np.testing.assert_array_equal(doc.shown_means(), posed.means)


def _subscribing_classes() -> dict[str, str]:
    """Every class in npga_view with a `subscriptions()` method -> its module's path."""
    out = {}
    for p in (ROOT / "npga_view").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ClassDef) and any(isinstance(b, ast.FunctionDef) and b.name == "subscriptions"
                                                      for b in node.body):
                out[node.name] = p.relative_to(ROOT).as_posix()
    return out


def _app_subscribers() -> list[str]:
    """The classes of the parts whose subscriptions `ViewerApp.__init__` includes, in order."""
    init = next(n for n in ast.walk(ast.parse((ROOT / "npga_view/app.py").read_text()))
                if isinstance(n, ast.FunctionDef) and n.name == "__init__")
    built = {t.attr: v.func.id for n in ast.walk(init) if isinstance(n, ast.Assign)
             for t, v in [(n.targets[0], n.value)]
             if isinstance(t, ast.Attribute) and isinstance(v, ast.Call) and isinstance(v.func, ast.Name)}
    loop = next(n for n in ast.walk(init) if isinstance(n, ast.For) and "subscriptions" in ast.unparse(n.body[0]))
    assert isinstance(loop.iter, ast.Tuple)
    return [built[e.attr] for e in loop.iter.elts if isinstance(e, ast.Attribute)]


RESET_CHECKED = {"EditController", "ShownCloud", "RefineController", "CompareController", "BakeController",
                 "PoseController", "ViewCamera"}


def test_every_subscriber_is_included_by_the_app_and_checked_here():
    assert set(_subscribing_classes()) == RESET_CHECKED
    assert sorted(_app_subscribers()) == sorted(RESET_CHECKED)


@pytest.fixture
def parts(ctx, tmp_path):
    """The subscribing parts built headless as the app builds them, and the document they subscribe to."""
    from npga_view.comparison.controller import CompareController
    from npga_view.controllers.bake import BakeController
    from npga_view.controllers.editing import EditController
    from npga_view.controllers.posing import PoseController
    from npga_view.controllers.refining import RefineController
    from npga_view.controllers.sequence_codes import SequenceCodes
    from npga_view.display import AppInfo
    from npga_view.rendering.factory import create_renderer
    from npga_view.rendering.live_detail import LiveDetail
    from npga_view.rendering.refinement import Refiner
    from npga_view.rendering.scheduler import DrawScheduler
    from npga_view.shown_cloud import ShownCloud
    from npga_view.view_camera import ViewCamera

    state, doc = ViewerState(), Document()
    renderer = create_renderer(ctx, 64, 64)
    lod = LiveDetail(lambda: create_renderer(ctx, 64, 64), renderer)
    draws = DrawScheduler(renderer, lod=lod)
    host = SimpleNamespace(state=state, doc=doc)
    edits = EditController(host)
    screen = ShownCloud(doc, state, renderer, lod, draws, edits, lambda: state.camera.camera(64, 64))
    host.screen = screen
    codes = SequenceCodes(state, lambda: doc.sequence)
    bakes = BakeController(state, lambda: doc.engine, codes)
    p = SimpleNamespace(
        state=state, doc=doc, edits=edits, screen=screen, bakes=bakes,
        refining=RefineController(Refiner(ctx, "cpu"), renderer, draws, state, AppInfo()),
        compare=CompareController(ctx), poses=PoseController(host, codes, bakes, keyframe_code=lambda: None),
        camera=ViewCamera(state, lambda: (0, 0, 64, 64), edits, dict, lambda: doc.sequence, lambda: 0))
    for part in (p.edits, p.screen, p.refining, p.compare, p.bakes, p.poses, p.camera):  # (the app's order)
        doc.include(part.subscriptions())
    yield p
    doc.close_engine()
    p.compare.release()
    p.refining.release()
    lod.close()
    edits.close()
    renderer.release()


def _dirty(p, tmp_path, old) -> None:
    """Leave in every part something of the avatar `old`."""
    from tests.support.captures import capture_cameras, write_capture

    p.doc.open(old)
    p.edits.session.selection[:5] = True
    p.state.inspect.picked = 7
    p.bakes.key = ("a sequence", "smoothing")
    p.poses.requested, p.poses.preview, p.poses.baked, p.poses.shown_frame = np.ones(3), True, True, 4
    p.state.camera.roll, p.state.camera.target = 40.0, [5.0, 5.0, 5.0]
    cams = capture_cameras(old)
    image = (np.full((56, 40, 3), 0.5), np.ones((56, 40)))
    write_capture(tmp_path, cams, dict.fromkeys(cams, image))
    codes = tmp_path / "codes.npzseq"
    ExpressionSequence(np.zeros((4, old.code_dim), np.float32), 25.0, "codes").save(codes)
    p.compare.sources.open_capture(tmp_path, codes)
    p.compare.sources.check_sequence(old.code_dim)  # (its codes fit the old avatar)


def test_every_subscriber_resets_when_another_avatar_opens(parts, tmp_path):
    p = parts
    old = make_synthetic_avatar(300, latent_dim=4, with_cnn=True, code_dim=20, n_components=8, seed=3, **SMALL)
    new = make_synthetic_avatar(200, code_dim=12, n_components=8, seed=4, **SMALL)
    _dirty(p, tmp_path, old)
    assert p.refining.refiner.has_cnn and p.compare.sources.capture is not None
    lod_resets = []
    real_reset = p.screen.lod.reset
    p.screen.lod.reset = lambda: (lod_resets.append(1), real_reset())

    p.doc.open(new)
    # edits: a new session of the new avatar, nothing selected
    assert p.edits.session.avatar is new and not p.edits.session.selection.any()
    # screen: the new avatar's inspector, nothing picked, the merged cloud grouped anew, the new pose shown
    assert p.screen.inspection.inspector.avatar is new and p.state.inspect.picked is None and lod_resets == [1]
    assert p.doc.posed is not None and len(p.doc.posed) == len(new)
    # refining: the new avatar's CNN (none) and nothing refined
    assert not p.refining.refiner.has_cnn and p.refining.key is None
    # compare: the capture's codes do not fit the new avatar: closed, and said
    assert p.compare.sources.capture is None and any("capture" in m for m in p.compare.messages)
    # bakes: the last worker's bake is gone
    assert p.bakes.key is None and p.bakes.state() == "none"
    # poses: nothing asked or in flight; an avatar without a worker is posed at once
    assert p.poses.requested is None and not p.poses.preview and not p.poses.baked and p.poses.shown_frame is None
    assert p.poses.first_pose_shown and not p.poses.canonical
    # camera: a fresh orbit camera framing the new avatar
    want = OrbitCamera(fov_y=p.state.camera.fov_y)
    want.frame(np.asarray(new.cloud.means), aspect=1.0)
    assert p.state.camera.roll == 0.0 and p.state.camera.target == want.target
    assert p.state.camera.distance == want.distance


def test_an_edited_cloud_reaches_every_part_that_holds_the_cloud(parts, tmp_path):
    p = parts
    avatar = make_synthetic_avatar(200, with_f=False, with_g=False, seed=5)  # static: re-posed here, no worker
    p.doc.open(avatar)
    p.bakes.key, p.poses.requested, p.state.inspect.picked = ("k",), np.ones(3), 150
    version = p.doc.version
    p.edits.session.selection[100:] = True
    p.edits.session.run(DeleteSelected())
    p.edits.after_actions()  # the edited cloud: the document's change_cloud
    n = len(p.edits.session.avatar)
    assert n == 100 and p.doc.version > version and len(p.doc.posed) == n
    assert p.bakes.key is None and p.poses.requested is None and p.state.inspect.picked is None
    assert p.screen.inspection.inspector.avatar is p.edits.session.avatar
