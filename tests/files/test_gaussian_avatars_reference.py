"""GaussianAvatars avatars posed by npga-view against THEIR forward (#37): FlameGaussianModel and FlameHead run from a
copy of ShenhanQian/GaussianAvatars (CC BY-NC-SA: run from where it lies, nothing of it copied here).

Set `NPGA_GA_SOURCE` to the copy (a checkout, or `git archive` of the fetched repository) and, when roma, plyfile
and iopath are not installed, `NPGA_GA_DEPS` to a folder holding them (`pip install --target DIR roma plyfile
iopath portalocker tqdm`). Their code wants CUDA and two CUDA extensions; the child process that runs it gets, from a
temporary folder outside the repository, a stand-in `simple_knn._C` (never called when posing) and `.cuda()` /
device="cuda" mapped to the CPU. The FLAME model is synthetic (tests/support/ga_synthetic.py) on FLAME's real topology,
their `flame_model/assets/flame/head_template_mesh.obj`, with a synthetic FLAME_masks.pkl (their FlameHead needs
one; posing reads only the lip ring ids of their own code from it).
"""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from npga_core.files.gaussian_avatars import import_gaussian_avatars
from npga_core.files.loading import load_sequence_for
from npga_core.posing.fastpose import FastPoser, posed_buffers
from tests.support import ga_synthetic as gs

SOURCE = os.environ.get("NPGA_GA_SOURCE", "")
REGIONS = ("face", "neck", "scalp", "boundary", "right_eyeball", "left_eyeball", "right_ear", "left_ear",
           "forehead", "eye_region", "nose", "lips", "right_eye_region", "left_eye_region")

RUNNER = textwrap.dedent('''
    import sys, numpy as np, torch
    _tensor = torch.tensor
    def _cpu_tensor(*a, **k):
        if str(k.get("device", "")).startswith("cuda"):
            k["device"] = "cpu"
        return _tensor(*a, **k)
    torch.tensor = _cpu_tensor
    torch.Tensor.cuda = lambda self, *a, **k: self
    torch.nn.Module.cuda = lambda self, *a, **k: self
    from scene.flame_gaussian_model import FlameGaussianModel
    ply, motion, out = sys.argv[1], sys.argv[2], sys.argv[3]
    gm = FlameGaussianModel(3)
    gm.load_ply(ply, has_target=False, motion_path=None if motion == "-" else motion)
    res = {}
    with torch.no_grad():
        for t in range(gm.num_timesteps):
            gm.select_mesh_by_timestep(t)
            res[f"xyz{t}"] = gm.get_xyz.numpy()
            res[f"scale{t}"] = gm.get_scaling.numpy()
            res[f"rot{t}"] = gm.get_rotation.numpy()
            res[f"opacity{t}"] = gm.get_opacity.numpy()
            res[f"sh{t}"] = gm.get_features.numpy()
    np.savez(out, **res)
''')


def _their_deps() -> str | None:
    """Why their code cannot run here, or None."""
    if not SOURCE:
        return "NPGA_GA_SOURCE is not set (a copy of ShenhanQian/GaussianAvatars)"
    if not (Path(SOURCE) / "scene" / "flame_gaussian_model.py").is_file():
        return f"NPGA_GA_SOURCE={SOURCE} holds no scene/flame_gaussian_model.py"
    probe = subprocess.run([sys.executable, "-c", "import roma, plyfile, iopath, tqdm, PIL"],
                           env=_env(Path("/nonexistent")), capture_output=True)
    return None if probe.returncode == 0 else "roma, plyfile, iopath, tqdm or PIL not importable (see NPGA_GA_DEPS)"


def _env(shims: Path) -> dict:
    path = [SOURCE, str(shims), os.environ.get("NPGA_GA_DEPS", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p), "CUDA_VISIBLE_DEVICES": ""}


pytestmark = pytest.mark.skipif(_their_deps() is not None, reason=str(_their_deps()))


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("ga_ref")
    src = Path(SOURCE)
    template, faces = gs.obj_topology(src / "flame_model/assets/flame/head_template_mesh.obj")
    assert template.shape == (gs.V, 3) and faces.shape == (gs.F, 3)  # FLAME's real topology
    flame = gs.flame_arrays(7, (template, faces))
    assets = d / "run" / "flame_model" / "assets" / "flame"
    assets.mkdir(parents=True)
    gs.write_flame_pickle(assets / "flame2023.pkl", flame, "numpy")
    rng = np.random.default_rng(0)
    masks = {k: np.sort(rng.choice(gs.V, 300, replace=False)) for k in REGIONS}
    (assets / "FLAME_masks.pkl").write_bytes(pickle.dumps(masks, protocol=2))
    for name in ("head_template_mesh.obj", "landmark_embedding_with_eyes.npy"):
        shutil.copy(src / "flame_model/assets/flame" / name, assets / name)
    shims = d / "shims" / "simple_knn"
    shims.mkdir(parents=True)
    (shims / "__init__.py").write_text("")
    (shims / "_C.py").write_text("def distCUDA2(points):\n    raise RuntimeError('not used when posing')\n")
    (d / "run" / "runner.py").write_text(RUNNER)
    gs.write_ga_folder(d / "out", 4000, seed=9, frames=3)
    foreign = gs.flame_params(21, 3, scale=1.5)
    np.savez(d / "foreign.npz", **foreign)
    ply = d / "out" / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    theirs = {}
    for key, motion in (("own", "-"), ("foreign", str(d / "foreign.npz"))):
        r = subprocess.run([sys.executable, "runner.py", str(ply), motion, str(d / f"their_{key}.npz")], cwd=d / "run",
                           env=_env(d / "shims"), capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-3000:]
        theirs[key] = dict(np.load(d / f"their_{key}.npz"))
    avatar = import_gaussian_avatars(d / "out", assets / "flame2023.pkl")
    return {"dir": d, "avatar": avatar, "theirs": theirs, "ply": ply}


@pytest.mark.parametrize("which", ["own", "foreign"])
def test_posed_attributes_equal_their_forward(world, which):
    avatar, theirs = world["avatar"], world["theirs"][which]
    source = world["ply"].parent / "flame_param.npz" if which == "own" else world["dir"] / "foreign.npz"
    seq = load_sequence_for(avatar, source)
    for t in range(len(seq)):
        xyz, scale, rot = theirs[f"xyz{t}"], theirs[f"scale{t}"], theirs[f"rot{t}"]
        head = float(np.ptp(xyz, axis=0).max())
        buf = posed_buffers(len(avatar), 16, 0)
        FastPoser(avatar).pose_into(seq.codes[t], buf)
        posed = avatar.pose(seq.codes[t])
        for means, quats, scales in ((posed.means, posed.quats, posed.scales),
                                     (buf["means"], buf["quats"], buf["scales"])):
            err = np.abs(means - xyz).max() / head
            assert err <= 1e-4, err
            np.testing.assert_allclose(scales, scale, rtol=1e-4, atol=0)  # their float32 face scale
            ours = Rotation.from_quat(quats[:, [1, 2, 3, 0]])
            angle = (ours.inv() * Rotation.from_quat(rot[:, [1, 2, 3, 0]] / np.linalg.norm(rot, axis=1,
                                                                                         keepdims=True))).magnitude()
            assert angle.max() < 1e-3, angle.max()  # radians; float32 frames of thin triangles
            print(f"{which} frame {t}: centres {err:.2e} of head size, scales {np.abs(scales / scale - 1).max():.2e} "
                  f"relative, rotations {angle.max():.2e} rad (median {np.median(angle):.1e})")
        np.testing.assert_array_equal(posed.opacities, theirs[f"opacity{t}"][:, 0])
        np.testing.assert_array_equal(posed.sh, theirs[f"sh{t}"])
