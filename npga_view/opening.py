"""Opening files in the window: an avatar (its pose worker, sliders, camera, the first pixels at once) and an
expression sequence (checked against the avatar), each remembered in the recent list.

Functions of the app (an `OpeningHost`: the app's open files and the controllers they reset), so that what
happens when a file opens reads in one place. Errors go to the UI (`state.report`); they return False.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from npga_core.errors import AvatarFileError, shown
from npga_core.files.loading import load_avatar, load_sequence_for
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.engine import PoseEngine
from npga_view.state import MAX_SLIDERS, ViewerState

if TYPE_CHECKING:
    from npga_view.controllers.bake import BakeController
    from npga_view.controllers.editing import EditController
    from npga_view.controllers.posing import PoseController
    from npga_view.controllers.refining import RefineController
    from npga_view.inspection_cache import InspectionCache
    from npga_view.rendering.live_detail import LiveDetail
    from npga_view.view_camera import ViewCamera
    from npga_view.window import Window


class OpeningHost(Protocol):
    """What opening a file changes in the app."""

    state: ViewerState
    avatar: Avatar | None
    engine: PoseEngine | None
    sequence: ExpressionSequence | None
    threads: int
    device: str
    precision: str
    legacy: bool
    remember_recent: bool
    window: Window | None
    edits: EditController
    poses: PoseController
    bakes: BakeController
    refining: RefineController
    lod: LiveDetail
    inspection: InspectionCache
    view_camera: ViewCamera
    _posed: PosedGaussians | None

    def show(self, posed: PosedGaussians) -> None: ...


def open_avatar(app: OpeningHost, path: str) -> bool:
    """Load an avatar (errors go to the UI); starts the pose worker for animatable ones. A GaussianAvatars
    output folder (or its point_cloud.ply) opens with the FLAME model the user gave (`state.flame_model`) through
    its cached `.npga` import, which the worker reopens by path; the status line says which happened."""
    try:
        opened, note = avatar_file(app.state, path)
        avatar = load_avatar(opened)
    except AvatarFileError as e:
        app.state.report(str(e))
        return False
    if note:
        app.state.tell(note)
    adopt_avatar(app, avatar, opened)
    app.edits.start(avatar, avatar.source)
    add_recent(app, path)
    if app.window is not None:
        app.window.set_title(f"npga-view - {shown(Path(path).name)}")  # no raw surrogates for glfw
    return True


def avatar_file(state: ViewerState, path: str) -> tuple[str, str]:
    """The file the window opens for `path` and a line saying what was done to get it ("" for most files)."""
    from npga_core.files.ga_cache import cached_import, is_ga_source

    if path == "demo" or not is_ga_source(path):
        return path, ""
    if not state.flame_model:
        raise AvatarFileError(path, "is a GaussianAvatars avatar, posed by FLAME: give your FLAME model (npga-view "
                              "view FOLDER --flame-model FLAME_PKL, or the Files panel's FLAME button)")
    out, note = cached_import(path, state.flame_model)
    return str(out), note


def adopt_avatar(app: OpeningHost, avatar: Avatar, path: str) -> None:
    """Show `avatar` (loaded from `path`): worker, sliders, camera; sequences that no longer fit close."""
    if app.engine is not None:
        app.engine.close()
        app.engine = None
    app.avatar = avatar
    st = app.state
    st.avatar_path = path if path == "demo" else str(Path(path).resolve())
    ex = avatar.expression
    k = ex.n_components if ex is not None else 0
    st.sliders = np.zeros(k, np.float32)
    if ex is not None and "neutral" in ex.named:  # open at the avatar's neutral face, not the mean code
        st.sliders = ex.to_sliders(ex.named["neutral"]).astype(np.float32)
    st.n_sliders = min(max(st.n_sliders, 1), max(1, min(k, MAX_SLIDERS)))
    app._posed = None
    app.poses.reset()
    app.inspection.set_avatar(avatar)
    app.refining.set_avatar(avatar)
    app.lod.reset()
    st.inspect.picked = None
    app.poses.first_pose_shown = False
    if avatar.dynamics is not None and avatar.source:
        start_engine(app, avatar.source)
        # first pixels at once: the canonical cloud, labelled, until the worker's first pose arrives
        if not app.legacy:
            app.poses.canonical = True
            app.show(avatar.cloud.posed_static())
    else:
        app.show(avatar.pose())
        app.poses.first_pose_shown = True
    if app.sequence is not None and app.sequence.dim != avatar.code_dim:
        st.report(f"{st.sequence_path}: codes have {app.sequence.dim} dims, the avatar expects "
                  f"{avatar.code_dim}; sequence closed")
        close_sequence(app)
    app.view_camera.frame_avatar(avatar, reset=True)


def start_engine(app: OpeningHost, path: str) -> None:
    """A new pose worker on the avatar file `path` (the open one, or the edited copy the editor wrote)."""
    if app.engine is not None:
        app.engine.close()
    a = app.avatar
    assert a is not None
    app.engine = PoseEngine(path, len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=app.threads,
                            device=app.device, precision=app.precision)
    app.bakes.forget()
    app.poses.engine_restarted()


def open_sequence(app: OpeningHost, path: str) -> bool:
    """Load a sequence; refused (with both dimensions) if it does not fit the avatar."""
    try:
        if app.avatar is None or app.avatar.code_dim == 0:
            raise AvatarFileError(path, "open an animatable avatar first (this one has no dynamics)")
        seq = load_sequence_for(app.avatar, path)
        seq.check_dim(app.avatar.code_dim, path)
    except AvatarFileError as e:
        app.state.report(str(e))
        return False
    for note in seq.notes:  # unmatched shapes, frames not recorded: once, as one line each
        app.state.report(note, note=True)
    app.sequence = seq
    app.poses.sequence_opened(len(seq), seq.fps)
    app.state.sequence_path = str(Path(path).resolve())
    app.state.timeline.time_s = 0.0
    app.state.follow_sequence = True
    add_recent(app, path)
    return True


def close_sequence(app: OpeningHost) -> None:
    app.sequence = None
    app.poses.sequence_closed()
    app.state.sequence_path = None


def add_recent(app: OpeningHost, path: str) -> None:
    app.state.add_recent(path)
    if app.remember_recent:
        app.state.save_recent()
