"""Any avatar as a LAM web avatar (`npga_core.files.lam_export.WebAvatar`): exact for a linear rig, fitted for
networks, with the centre error measured on held-out frames.

Every avatar is driven by ARKit weights w the way the window drives it: ``z = basis.codes(S w)``, S the name
match of ARKit's names to the avatar's blendshape basis (`match_names`), z its frame vector. LAM's player draws
``centre_i = vertex_i + offset_i + sum_j s_j w_j delta_j,i`` (s_j its weight scales), so:

- **exact** (`exact_web_avatar`): an avatar posed by a `LinearRig` alone is linear in w: with rig weights
  ``v = scale * z + bias`` and rig deltas D, ``delta_j = sum_k scale_k (M S)_kj D_k / s_j`` (M the basis matrix);
  the constant part (basis offset, rig bias) goes into the offsets, the rig's rest transform into the vertices,
  offsets and deltas; rotations, scales, opacity and colour are the stored ones (the player does not turn them).
- **fitted** (`fit_web_avatar`): networks are not linear in w. The exact centres are computed (`FastPoser` in
  float32 on the networks that move centres) at training frames of ARKit weights; the deltas are the least-squares
  solution of ``centre(w_t) - centre(0) ~ sum_j w_j s_j delta_j`` over them (a small ridge keeps shapes the
  frames never move at 0), deltas under `DROP` of the head size per unit weight dropped; the mesh vertex is the
  canonical centre and the offset the exact displacement at w = 0 (the neutral face is exact). Rotation, scale,
  opacity and colour are the avatar's at w = 0; a CNN is lost; view-dependent colour (SH above degree 0) is baked
  as seen from the front (`baked_rgb`): the player draws SH degree 0 only.

`measure` compares the centres the player would draw (`WebAvatar.centres`) with the exact ones on held-out
frames: RMS, p99 and max error in metres and as a fraction of the head size (the diagonal of the centres' box).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from npga_core.files.arkit_takes import read_take
from npga_core.files.blendshape_names import ARKIT_52, match_names
from npga_core.files.lam import PLAYER_SCALE
from npga_core.files.lam_export import LAM_HEAD_CENTRE, WebAvatar
from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import Dynamics
from npga_core.model.gaussians import SH_C0, logit
from npga_core.model.sh import sh_basis
from npga_core.posing.fastpose import FastPoser, posed_buffers

#: Deltas smaller than this fraction of the head size per unit weight are dropped (sparser targets).
DROP = 1e-4
#: The ridge, relative to the mean of the weights' Gram diagonal: shapes no frame moves get 0, shapes that always
#: move together (left and right in a take) split their motion evenly instead of into large opposite deltas.
RIDGE = 1e-4
#: Avatars whose centre lies farther than this (metres) from LAM's head centre are moved there.
PLACE_WITHIN = 0.3
GENERATED = "generated"
#: View-dependent colour (SH above degree 0) is baked as seen from this far in front of the face (metres).
BAKE_EYE = 1.0


class FitError(ValueError):
    """An avatar that cannot be exported as a LAM web avatar (no basis, no matching names), one line."""


@dataclass
class Frames:
    """ARKit weights (T, J) over `names` and where they came from."""

    weights: np.ndarray
    label: str


def target_names(avatar: Avatar) -> tuple[str, ...]:
    """The morph targets written: ARKit's 52 names without tongueOut (LAM's 51), with tongueOut when the avatar's
    basis has it."""
    basis = avatar.blendshapes
    if basis is None:
        return tuple(n for n in ARKIT_52 if n != "tongueOut")
    moved = set(ARKIT_52) - set(match_names(ARKIT_52, basis.names).missing)
    return tuple(n for n in ARKIT_52 if n != "tongueOut" or n in moved)


def require_drivable(avatar: Avatar) -> None:
    """FitError (one line) for an avatar ARKit weights cannot drive: static, or without a blendshape basis."""
    if avatar.dynamics is None:
        raise FitError("the avatar is static (no dynamics): nothing for ARKit weights to move")
    if avatar.blendshapes is None:
        raise FitError("the avatar has no blendshape basis (ARKit weights -> codes): fit one with "
                       "`npga-view fit-blendshapes --take TAKE --codes SEQ --out basis.npz`")


def frame_vectors(avatar: Avatar, names: tuple[str, ...], weights: np.ndarray) -> np.ndarray:
    """Frame vectors (T, D) of ARKit weights (T, J) over `names`, as the window makes them."""
    require_drivable(avatar)
    basis = avatar.blendshapes
    assert basis is not None
    try:
        match = match_names(names, basis.names)
    except ValueError as e:
        raise FitError(f"the avatar's blendshape basis matches no ARKit name ({e})") from None
    z = basis.codes(match.apply(np.asarray(weights, np.float64)))
    return np.stack([avatar.check_code(row) for row in np.atleast_2d(z)])


def head_size(centres: np.ndarray) -> float:
    """The diagonal of the centres' bounding box."""
    c = np.asarray(centres, np.float64)
    return float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))


def placement(centres: np.ndarray) -> np.ndarray:
    """The translation (3,) into LAM's frame: none when the box centre is already near LAM's head centre."""
    c = np.asarray(centres, np.float64)
    mid = (c.max(axis=0) + c.min(axis=0)) / 2.0
    target = np.asarray(LAM_HEAD_CENTRE)
    return np.zeros(3) if np.linalg.norm(mid - target) <= PLACE_WITHIN else target - mid


def player_scales(names: tuple[str, ...]) -> np.ndarray:
    return np.array([PLAYER_SCALE.get(n, 1.0) for n in names], np.float64)


def baked_rgb(sh: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """RGB in 0..1 (N, 3) the player can draw (it has SH degree 0): the colour seen from a frontal eye `BAKE_EYE`
    metres in front of the head's box centre (+z, where faces look), view-dependent terms included; the DC
    colour alone for SH degree 0."""
    sh = np.asarray(sh, np.float64)
    if sh.shape[1] == 1:
        return np.clip(0.5 + SH_C0 * sh[:, 0], 0.0, 1.0).astype(np.float32)
    c = np.asarray(centres, np.float64)
    eye = (c.max(axis=0) + c.min(axis=0)) / 2.0 + np.array([0.0, 0.0, BAKE_EYE])
    d = c - eye
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1
    colour = np.einsum("nk,nkc->nc", sh_basis(d, degree), sh) + 0.5
    return np.clip(colour, 0.0, 1.0).astype(np.float32)


# -- exact -----------------------------------------------------------------------------------------------------
def is_exact(avatar: Avatar) -> bool:
    """True when the avatar is posed by a linear rig alone (its export is exact)."""
    d = avatar.dynamics
    return d is not None and d.rig is not None and d.rig.skin is None and d.network_dim == 0


def exact_web_avatar(avatar: Avatar, names: tuple[str, ...]) -> tuple[WebAvatar, np.ndarray]:
    """The web avatar of a rig-only avatar and the translation applied (LAM's frame)."""
    d = avatar.dynamics
    assert d is not None and d.rig is not None and avatar.blendshapes is not None
    rig, basis = d.rig, avatar.blendshapes
    match = match_names(names, basis.names)
    lin = basis.matrix.astype(np.float64) @ match.matrix  # (K, J): frame vector per ARKit weight
    coef = rig.scale.astype(np.float64)[:, None] * lin  # runtime weight per ARKit weight
    const = rig.scale.astype(np.float64) * basis.offset.astype(np.float64) + rig.bias
    n = len(avatar)
    deltas = np.zeros((len(names), n, 3))
    deltas[:, rig.support] = np.einsum("kj,ksc->jsc", coef, rig.deltas.astype(np.float64))
    deltas /= player_scales(names)[:, None, None]
    cloud = avatar.cloud
    means = cloud.means.astype(np.float64)
    vertices = means.copy() if rig.vertices is None else rig.vertices.astype(np.float64)
    offsets = means - vertices
    offsets[rig.support] += np.einsum("k,ksc->sc", const, rig.deltas.astype(np.float64))
    m = rig.transform
    a = m[:3, :3]
    vertices = vertices @ a.T + m[:3, 3]
    offsets, deltas = offsets @ a.T, deltas @ a.T
    shift = placement(vertices + offsets)
    vertices += shift
    if rig.turns_covariance and not rig.identity_transform:
        posed = avatar.pose(frame_vectors(avatar, names, np.zeros((1, len(names))))[0])
        quats, log_scales = posed.quats, np.log(np.maximum(posed.scales, 1e-30))
    else:
        quats, log_scales = cloud.quats, cloud.log_scales
    web = WebAvatar(vertices=vertices, offsets=offsets, rgb=baked_rgb(cloud.sh, means),
                    opacity_logits=cloud.opacity_logits, log_scales=log_scales, quats=quats, names=names,
                    deltas=deltas)
    unused = [c for c, used in zip(basis.names, np.any(match.matrix != 0, axis=1), strict=True) if not used]
    web.notes["export"] = ("exact: the avatar is a linear blendshape rig; the player poses it as npga-view does"
                           + (f" (channels no ARKit name drives, left out: {', '.join(unused[:8])})" if unused else ""))
    return web, shift


# -- fitted ----------------------------------------------------------------------------------------------------
def _centre_avatar(avatar: Avatar) -> tuple[Avatar | None, slice]:
    """An avatar with only what moves the centres (networks with a position output, the rig) and the part of
    the frame vector it takes; None when nothing moves them."""
    d = avatar.dynamics
    assert d is not None
    nets = {k: n for k, n in d.networks().items() if any(a == "position" for a, _ in n.config.outputs)}
    if not nets and d.rig is None:
        return None, slice(0, 0)
    keep = slice(0, d.code_dim) if nets else slice(d.network_dim, d.code_dim)
    dyn = Dynamics(networks=nets, rules=dict(d.rules), condition=d.condition if nets else None,
                   blend_notes=dict(d.blend_notes), rig=d.rig)
    return Avatar(avatar.cloud, dyn, units=avatar.units), keep


class Centres:
    """Exact centres (N, 3) at ARKit weights, through the networks that move them (float32 `FastPoser`)."""

    def __init__(self, avatar: Avatar, names: tuple[str, ...], threads: int = 2):
        self.avatar, self.names = avatar, names
        self.moving, self.keep = _centre_avatar(avatar)
        self.poser = None if self.moving is None else FastPoser(self.moving, threads=threads, precision="fp32")
        self.dest = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)

    def __call__(self, weights: np.ndarray) -> np.ndarray:
        if self.poser is None:
            return self.avatar.cloud.means.astype(np.float64)
        z = frame_vectors(self.avatar, self.names, np.asarray(weights)[None])[0]
        self.poser.pose_into(z[self.keep], self.dest)
        return self.dest["means"].astype(np.float64)


Progress = Callable[[int, int], None]


def fit_web_avatar(avatar: Avatar, names: tuple[str, ...], train: Frames, centres: Centres | None = None,
                   progress: Progress | None = None) -> tuple[WebAvatar, np.ndarray, dict]:
    """The fitted web avatar, the translation applied and the fit's numbers (frames, in-sample RMS)."""
    if avatar.dynamics is None:
        raise FitError("the avatar is static (no dynamics): there is nothing to fit")
    centres = centres or Centres(avatar, names)
    zero = np.zeros(len(names))
    rest = centres(zero)
    x = np.asarray(train.weights, np.float64)
    gram = x.T @ x
    cross = np.zeros((len(names), rest.size))
    sq = 0.0
    for t, row in enumerate(x):
        y = (centres(row) - rest).reshape(-1)
        cross += np.outer(row, y)
        sq += float(y @ y)
        if progress is not None:
            progress(t + 1, len(x))
    ridge = RIDGE * max(float(np.trace(gram)) / len(names), 1e-12)
    beta = np.linalg.solve(gram + ridge * np.eye(len(names)), cross)
    resid = sq - 2.0 * float(np.sum(beta * cross)) + float(np.sum(beta * (gram @ beta)))
    size = head_size(rest)
    deltas = beta.reshape(len(names), -1, 3)
    dropped = np.linalg.norm(deltas, axis=2) < DROP * size
    deltas[dropped] = 0.0
    deltas /= player_scales(names)[:, None, None]
    z0 = frame_vectors(avatar, names, zero[None])[0]
    full = FastPoser(avatar, threads=2, precision="fp32")
    posed = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)
    full.pose_into(z0, posed)
    canonical = avatar.cloud.means.astype(np.float64)
    shift = placement(rest)
    web = WebAvatar(vertices=canonical + shift, offsets=rest - canonical, rgb=baked_rgb(posed["sh"], rest),
                    opacity_logits=logit(posed["opacities"]), log_scales=np.log(np.maximum(posed["scales"], 1e-30)),
                    quats=posed["quats"], names=names, deltas=deltas)
    silent = [n for n, v in zip(names, np.abs(x).max(axis=0) if len(x) else zero, strict=True) if v < 0.05]
    info = {"frames": len(x), "frames_from": train.label,
            "in_sample_rms_m": math.sqrt(max(resid, 0.0) / max(rest.size // 3 * len(x), 1)),
            "dropped_deltas_below_m": DROP * size, "deltas_kept": int((~dropped).sum()),
            "channels_never_moved_in_training": silent}
    web.notes["export"] = (f"fitted: morph deltas are the least-squares fit of the exact centres over {len(x)} "
                           f"frames ({train.label}); the mesh vertex is the canonical centre, the offset the exact "
                           "displacement at zero weights")
    return web, shift, info


# -- frames ----------------------------------------------------------------------------------------------------
def generated_frames(names: tuple[str, ...], count: int, seed: int, units: bool = True) -> Frames:
    """Single-channel unit activations (when `units`) then random sparse combinations (2-6 channels at
    0.2..1) up to `count` frames."""
    rng = np.random.default_rng(seed)
    j = len(names)
    rows = [np.eye(j)] if units else []
    extra = max(count - (j if units else 0), 0)
    combos = np.zeros((extra, j))
    for row in combos:
        on = rng.choice(j, int(rng.integers(2, 7)), replace=False)
        row[on] = rng.uniform(0.2, 1.0, len(on))
    rows.append(combos)
    what = (f"{j} single-channel unit activations and " if units else "") + \
        f"{extra} random sparse combinations (2-6 channels at 0.2..1, seed {seed})"
    return Frames(np.concatenate(rows), f"generated: {what}")


def take_weights(path: str, names: tuple[str, ...]) -> np.ndarray:
    """A take's recorded rows as ARKit weights (T, J) over `names` (AvatarFileError for a bad file)."""
    from npga_core.errors import AvatarFileError

    take = read_take(path)
    try:
        match = match_names(take.names, names)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    return match.apply(take.weights)


def _spread(w: np.ndarray, most: int) -> np.ndarray:
    if len(w) <= most:
        return w
    return w[np.unique(np.linspace(0, len(w) - 1, most).round().astype(int))]


def plan_frames(takes: list[str], test_take: str | None, names: tuple[str, ...], max_train: int,
                max_test: int) -> tuple[Frames, Frames]:
    """Training and held-out frames: `takes` (the word 'generated' adds the generated frames) for training and
    `test_take` held out; without `test_take`, the last of several takes is held out, one take is split (its
    first 80% trains, the last 20% tests), and no take means generated frames with a generated held-out set."""
    files = [t for t in takes if t != GENERATED]
    generated = GENERATED in takes or not files
    test: Frames | None = None
    if test_take is not None:
        test = Frames(_spread(take_weights(test_take, names), max_test), test_take)
    elif len(files) >= 2:
        test = Frames(_spread(take_weights(files[-1], names), max_test), files[-1])
        files = files[:-1]
    parts, labels = [], []
    for f in files:
        w = take_weights(f, names)
        if test is None and len(files) == 1 and not generated:
            cut = max(1, int(0.8 * len(w)))
            test = Frames(_spread(w[cut:], max_test), f"{f} rows {cut}..{len(w) - 1} (its last 20%)")
            w = w[:cut]
            labels.append(f"{f} rows 0..{cut - 1}")
        else:
            labels.append(f)
        parts.append(w)
    share = max_train // (len(parts) + (1 if generated else 0))
    parts = [_spread(w, share) for w in parts]
    if generated:
        g = generated_frames(names, max(share, len(names) + 1), seed=0)
        parts.append(g.weights)
        labels.append(g.label)
    if test is None:
        test = generated_frames(names, max_test, seed=1, units=False)
    return Frames(np.concatenate(parts), "; ".join(labels)), test


# -- measuring -------------------------------------------------------------------------------------------------
def measure(web: WebAvatar, shift: np.ndarray, centres: Centres, test: Frames,
            progress: Progress | None = None) -> dict:
    """The player's centres against the exact ones over the held-out frames (in the avatar's own frame)."""
    errors, motion = [], []
    rest = centres(np.zeros(len(centres.names)))
    size = head_size(rest)
    for t, row in enumerate(np.asarray(test.weights)):
        exact = centres(row)
        drawn = web.centres(dict(zip(web.names, row.tolist(), strict=True))) - shift
        errors.append(np.linalg.norm(drawn - exact, axis=1))
        motion.append(np.linalg.norm(exact - rest, axis=1))
        if progress is not None:
            progress(t + 1, len(test.weights))
    e = np.concatenate(errors) if errors else np.zeros(1)
    mv = np.concatenate(motion) if motion else np.zeros(1)
    rms, p99 = float(np.sqrt(np.mean(e**2))), float(np.percentile(e, 99))
    return {"frames": len(test.weights), "frames_from": test.label, "head_size_m": size,
            "rms_m": rms, "p99_m": p99, "max_m": float(e.max()),
            "rms_of_head": rms / size, "p99_of_head": p99 / size,
            "motion_rms_m": float(np.sqrt(np.mean(mv**2))), "motion_p99_m": float(np.percentile(mv, 99))}
