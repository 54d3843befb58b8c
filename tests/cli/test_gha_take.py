"""A Gaussian-Head-Avatar checkpoint driven by an ARKit take through a basis fitted from a paired take and the
avatar's tracked codes, end to end through the command line (each command its own process, a forked child of the
project's fork server; exit 0):

1. the paired data: a 30 Hz Live Link Face take (on the app's 60-count timecode, FF stepping by 2, as the app writes
   30 Hz takes) and, for the same frames, GHA tracking output (`params/NNNN/params.npz` with ``exp_coeff`` (1, E),
   ``pose`` (1, 6), ``scale`` (1,), the layout GHA's lib/dataset/Dataset.py reads) whose expression codes are a
   linear function of the take's weights plus tracking noise;
2. `npga-view fit-blendshapes --take --codes --out basis.npz` and `... --into CHECKPOINT --out with_basis.npga`;
3. `export CHECKPOINT --basis basis.npz --sequence take.csv --frame K` and `export with_basis.npga --sequence
   take.csv --frame K` each write the same Gaussians as `export CHECKPOINT --expr z_K.npy`, z_K being the fitted
   map of row K, for a take in the app's CSV column order and one in the packet order (PyLiveLinkFace,
   pylivelinkface.py lines 12-73: JawLeft before JawRight, MouthLeft before MouthRight; the app's order is the
   LiveLinkFace Blender add-on's LIVE_LINK_FACE_HEADER, tests/support/takes.py `CSV_SHAPES`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from npga_core.files.basis_file import read_basis
from npga_core.files.blendshape_names import ANGLE_NAMES, ARKIT_52, canonical_arkit, match_names
from npga_core.files.checkpoint import read_avatar
from npga_core.files.gha_synthetic import write_gha_folder
from npga_core.files.ply import read_ply
from tests.support.takes import CSV_SHAPES

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"feature_dim": 12, "exp_dim": 8, "hidden": 32, "channels": 8, "freqs": 2, "capacity": 4}
ROWS, RATE, NOISE = 150, 30, 0.01
DEAD = ("tongueOut", "cheekPuff", "noseSneerLeft", "noseSneerRight", "mouthRollUpper")  # never moved in the take


@pytest.fixture(scope="module")
def cli(tmp_path_factory):
    """`npga-view ARGV` in its own process: a forked child of the project's fork server
    (tests/support/cli_forkserver.py), which imports the project once."""
    from tests.support.cli_forkserver import ForkServer

    server = ForkServer(tmp_path_factory.mktemp("gha_take_cli"), env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})

    def run(*argv: str) -> str:
        reply, out, err = server.cli(*argv)
        assert reply["exit"] == 0, (argv, reply, out[-2000:], err[-2000:])
        return out + err

    yield run
    server.close()


def _write_take(path: Path, w: np.ndarray, columns: list[str]) -> None:
    """Rows at 30 Hz on a 60-count timecode (FF = 0, 2, 4, ...), angles recorded as zeros, as the app writes."""
    lines = [",".join(["Timecode", "BlendShapeCount", *columns, *ANGLE_NAMES])]
    for k, row in enumerate(w):
        vals = dict(zip(ARKIT_52, row, strict=True))
        tc = f"14:03:{(k // RATE) % 60:02d}:{(k % RATE) * 2:02d}.000"
        lines.append(",".join([tc, "61", *(f"{vals[canonical_arkit(c)]:.9g}" for c in columns),
                               *("0" for _ in ANGLE_NAMES)]))
    path.write_text("\n".join(lines) + "\n")


def _write_tracking(root: Path, exp: np.ndarray) -> Path:
    """GHA's tracked frames: params/NNNN/params.npz (exp_coeff (1, E), pose (1, 6), scale (1,))."""
    for t, e in enumerate(exp):
        d = root / "params" / f"{t:04d}"
        d.mkdir(parents=True, exist_ok=True)
        np.savez(d / "params.npz", exp_coeff=e[None].astype(np.float32), pose=np.zeros((1, 6), np.float32),
                 scale=np.ones(1, np.float32))
    return root


@pytest.fixture(scope="module")
def paired(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gha_take")
    rng = np.random.default_rng(35)
    ckpt = write_gha_folder(tmp / "ckpt", n=700, seed=11, **SMALL)
    e = SMALL["exp_dim"]
    w = rng.uniform(0, 1, (ROWS, 52)) * (rng.uniform(0, 1, (ROWS, 52)) < 0.4)
    w[:, [ARKIT_52.index(n) for n in DEAD]] = 0.0
    truth_a, truth_b = 0.6 * rng.standard_normal((e, 52)), 0.2 * rng.standard_normal(e)
    exp = w @ truth_a.T + truth_b + NOISE * rng.standard_normal((ROWS, e))  # the tracker's codes
    takes = {"app_order": tmp / "app_order.csv", "packet_order": tmp / "packet_order.csv"}
    _write_take(takes["app_order"], w, CSV_SHAPES)
    _write_take(takes["packet_order"], w, [n[0].upper() + n[1:] for n in ARKIT_52])
    tracking = _write_tracking(tmp / "tracking", exp)
    return tmp, ckpt, w, (truth_a, truth_b), takes, tracking


def test_a_gha_avatar_is_driven_by_a_take_through_a_basis_fitted_from_tracked_codes(paired, cli):
    tmp, ckpt, w, (truth_a, truth_b), takes, tracking = paired
    e = SMALL["exp_dim"]
    basis_path, into = tmp / "basis.npz", tmp / "with_basis.npga"
    text = cli("fit-blendshapes", "--take", str(takes["app_order"]), "--codes", str(tracking), "--out",
                str(basis_path))
    assert f"from {ROWS} frames at 30 fps" in text and f"{len(DEAD)} shapes never move" in text
    cli("fit-blendshapes", "--take", str(takes["packet_order"]), "--codes", str(tracking), "--into", str(ckpt),
         "--out", str(into))
    basis, own = read_basis(basis_path), read_avatar(into).blendshapes
    assert own is not None and sorted(own.names) == sorted(basis.names)
    assert not set(DEAD) & {canonical_arkit(n) for n in basis.names}  # left out, as the fit said
    # the fit recovers the tracker's relation to within its noise (expression part; the pose part is 0)
    m = match_names(ARKIT_52, basis.names)
    fitted = basis.codes(m.apply(w))
    assert np.sqrt(np.mean((fitted[:, :e] - (w @ truth_a.T + truth_b)) ** 2)) < 3 * NOISE
    np.testing.assert_allclose(fitted[:, e:], 0.0, atol=1e-4)
    np.testing.assert_allclose(own.codes(match_names(ARKIT_52, own.names).apply(w)), fitted, atol=1e-4)
    for k in (0, 77):  # frame K is row K of the 30 Hz take
        z = tmp / f"z{k}.npy"
        np.save(z, fitted[k].astype(np.float32))
        want = read_ply(Path(_ply(cli, tmp, f"expr{k}", "export", str(ckpt), "--expr", str(z))))
        for order, take in takes.items():
            got = {"--basis": _ply(cli, tmp, f"{order}{k}b", "export", str(ckpt), "--basis", str(basis_path),
                                   "--sequence", str(take), "--frame", str(k)),
                   "--into": _ply(cli, tmp, f"{order}{k}i", "export", str(into), "--sequence", str(take),
                                  "--frame", str(k))}
            for how, path in got.items():
                g = read_ply(Path(path))
                msg = f"{order} {how} frame {k}"
                np.testing.assert_allclose(g.means, want.means, atol=2e-5, err_msg=msg)
                np.testing.assert_allclose(g.sh, want.sh, atol=2e-5, err_msg=msg)
                np.testing.assert_allclose(g.log_scales, want.log_scales, atol=2e-5, err_msg=msg)
                np.testing.assert_allclose(g.opacity_logits, want.opacity_logits, atol=2e-5, err_msg=msg)
    # and the expression moves the avatar: two rows' clouds differ well beyond that tolerance
    a, b = read_ply(tmp / "expr0.ply"), read_ply(tmp / "expr77.ply")
    assert np.abs(a.means - b.means).max() > 1e-3


def _ply(cli, tmp: Path, name: str, *argv: str) -> str:
    out = tmp / f"{name}.ply"
    cli(*argv, "--out", str(out))
    return str(out)
