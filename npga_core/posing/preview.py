"""Preview posing for slider scrubbing: the exact offsets of a base code plus probe deltas spread to all Gaussians.

When the code moves from z0 (whose exact offsets O(z0) are known) to z1, the networks run only on P probe
Gaussians, and each Gaussian's change is a weighted sum of the changes of its K nearest probes:

    O~(z1)_i = O(z0)_i + sum_j w_ij (O(z1) - O(z0))_{probe j}

The probes run the networks themselves (`ProbeNets`: float32, or bfloat16 where this CPU multiplies that
faster). The weights start as inverse squared canonical distances (`PreviewModel.geometric`, instant)
and are then fitted per Gaussian to offsets of sampled codes (`PreviewModel.fit`, a few full evaluations): a
ridge regression of each Gaussian's offset change on its probes' changes, which also learns which probes move
together with it (a lip Gaussian next to the other lip). The fit also measures each Gaussian's sensitivity
(mean squared change over the sampled codes, per attribute block normalised), and probes are drawn with
probability growing with it, so that Gaussians that barely move cost few probes (on the demo avatar this
matters more than the fit itself, see docs/PERFORMANCE.md). A fitted model is saved next to the avatar, keyed
by the avatar's content hash (`save` / `load`).

The error is measured, not assumed: `npga-view bench` renders preview and exact images of the same codes.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.places import cache_folder_for
from npga_core.files.untrusted import bounded_floats, parse_json, read_npz, real_floats
from npga_core.model.avatar import Avatar
from npga_core.posing.fastpose import FastPoser, Lane
from npga_core.schema import decode_file, number

PREVIEW_FORMAT = 1
MAX_CACHED_NEIGHBOURS = 64  # probes per Gaussian accepted from a cache file
#: Largest magnitude of a cached interpolation weight (geometric weights are in [0, 1], fitted ones near).
MAX_WEIGHT = 1e4


@dataclass
class PreviewModel:
    """Probes and interpolation weights of one avatar (see the module docstring)."""

    probes: np.ndarray  # (P,) int64 row indices, ascending
    neighbours: np.ndarray  # (N, K) int64 indices into `probes`
    weights: np.ndarray  # (N, K) float32
    sensitivity: np.ndarray | None = None  # (N,) float32, mean squared normalised change over sampled codes
    fitted_codes: int = 0  # number of sampled codes the weights were fitted to (0: geometric weights)
    key: str = ""  # content key of the avatar it belongs to

    @property
    def n_probes(self) -> int:
        return int(self.probes.shape[0])

    @staticmethod
    def geometric(means: np.ndarray, n_probes: int = 2048, k: int = 8, seed: int = 0,
                  sensitivity: np.ndarray | None = None) -> PreviewModel:
        """Probes drawn at random (more where `sensitivity` is high), inverse-square-distance weights."""
        means = np.asarray(means, np.float32)
        n = means.shape[0]
        p_count = max(1, min(n, int(n_probes)))
        probes = _draw_probes(n, p_count, np.random.default_rng(seed), sensitivity)
        k = max(1, min(k, p_count))
        dist, idx = cKDTree(means[probes]).query(means, k)
        dist, idx = dist.reshape(n, k), idx.reshape(n, k).astype(np.int64)
        w = 1.0 / np.maximum(dist, 1e-9) ** 2
        w /= w.sum(axis=1, keepdims=True)
        w = w.astype(np.float32)
        model = PreviewModel(probes, idx, w, sensitivity)
        model._pin_probes()
        return model

    def _pin_probes(self) -> None:
        """A probe takes its own exact change: weight 1 on itself, 0 elsewhere."""
        self.neighbours[self.probes] = np.arange(self.n_probes)[:, None]
        self.weights[self.probes] = 0.0
        self.weights[self.probes, 0] = 1.0

    # -- fitting -------------------------------------------------------------------------------------------
    @staticmethod
    def sample_codes(avatar: Avatar, count: int, seed: int = 0, scale: float = 1.0) -> np.ndarray:
        """`count` codes from the avatar's expression space (slider values ~ N(0, scale^2))."""
        rng = np.random.default_rng(seed)
        ex = avatar.expression
        if ex is None:
            return (rng.standard_normal((count, avatar.code_dim)) * scale).astype(np.float32)
        return np.stack([ex.sample(rng, scale=scale) for _ in range(count)]).astype(np.float32)

    @staticmethod
    def fit(poser: FastPoser, codes: np.ndarray, reference: np.ndarray, n_probes: int = 2048, k: int = 8,
            ridge: float = 1e-2, seed: int = 0) -> PreviewModel:
        """Sensitivity-weighted probes and fitted weights from exact offsets at `codes` (see `PreviewFit`)."""
        job = PreviewFit(poser, codes, reference, n_probes, k, ridge, seed)
        while not job.step():
            pass
        assert job.model is not None
        return job.model

    # -- cache file ----------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the model (atomically) as an .npz with its key and format in the header."""
        meta = json.dumps({"format": PREVIEW_FORMAT, "key": self.key, "fitted_codes": self.fitted_codes})
        arrays = {"probes": self.probes, "neighbours": self.neighbours.astype(np.int32), "weights": self.weights,
                  "meta": np.frombuffer(meta.encode(), np.uint8)}
        if self.sensitivity is not None:
            arrays["sensitivity"] = self.sensitivity.astype(np.float32)
        atomic_write(Path(path), lambda fh: np.savez(fh, **arrays))  # type: ignore[arg-type]

    @staticmethod
    def load(path: str | Path, key: str, n: int) -> PreviewModel | None:
        """The model stored at `path` if it was built for content `key` with `n` Gaussians, else None.

        The cache is untrusted (`npga_core.files.untrusted.read_npz`: regular file, sizes from the headers
        within a budget for `n` Gaussians, numbers only); indices out of range or non-finite weights are a miss.
        """
        budget = 4096 + n * (8 * 2 * MAX_CACHED_NEIGHBOURS + 16)
        try:
            f = read_npz(path, budget, keys=("probes", "neighbours", "weights", "sensitivity", "meta"), max_members=8)
            text = f["meta"].astype(np.uint8).tobytes()
            meta = decode_file(parse_json(text, path, max_depth=4), dict[str, Any], path, "meta")
            if meta.get("format") != PREVIEW_FORMAT or meta.get("key") != key:
                return None
            probes, neighbours, weights = f["probes"], f["neighbours"], f["weights"]
            if (probes.ndim != 1 or not 1 <= probes.size <= n or probes.dtype.kind not in "iu"
                    or neighbours.ndim != 2 or neighbours.shape[0] != n or neighbours.dtype.kind not in "iu"
                    or not 1 <= neighbours.shape[1] <= MAX_CACHED_NEIGHBOURS or weights.shape != neighbours.shape):
                return None
            if (probes.min() < 0 or probes.max() >= n or (np.diff(probes) <= 0).any() or neighbours.min() < 0
                    or neighbours.max() >= probes.size):
                return None
            sens = f.get("sensitivity")
            if sens is not None and sens.shape != (n,):
                return None
            model = PreviewModel(probes.astype(np.int64), neighbours.astype(np.int64),
                                 bounded_floats(weights, path, "weights", MAX_WEIGHT),
                                 None if sens is None else real_floats(sens, path, "sensitivity"),
                                 number(meta.get("fitted_codes", 0), "fitted_codes", 0, 2**20, whole=True), key)
        except (AvatarFileError, OSError, ValueError, KeyError):
            return None
        return model


def preview_cache_path(avatar_path: str | Path, key: str, probes: int, k: int, fit_codes: int,
                       cache_dir: str | Path | None = None) -> Path:
    """Where the fitted preview model of an avatar is cached: in `cache_dir`, else next to the avatar when its
    folder is writable and not the bundled demo, else in the user cache folder's `previews/`."""
    p = Path(avatar_path)
    folder = Path(cache_dir) if cache_dir is not None else cache_folder_for(p, "previews")
    return folder / f"{p.name}.preview-{key[:20]}-{probes}-{k}-{fit_codes}.npz"


class PreviewFit:
    """A resumable `PreviewModel.fit`: call `step()` until it returns True, then read `model`.

    Steps: the reference offsets (plus the column scales from a row sample), one step per code for the
    sensitivity, the probe draw, one step per code for the regression: 2 x len(codes) + 1 full evaluations
    in all. `step(cancel)` gives up a step when `cancel()` turns true and repeats it next time, so a worker
    can fit between requests without delaying them by more than a chunk.
    """

    def __init__(self, poser: FastPoser, codes: np.ndarray, reference: np.ndarray, n_probes: int = 2048,
                 k: int = 8, ridge: float = 1e-2, seed: int = 0):
        self.poser, self.codes, self.reference = poser, np.asarray(codes, np.float32), reference
        self.n_probes, self.k, self.ridge, self.seed = n_probes, k, ridge, seed
        self.total = 2 * len(self.codes) + 2
        self.done = 0
        self.model: PreviewModel | None = None
        self._ref = self._scale = self._a = self._b = torch.empty(0)
        self._sens = torch.zeros(poser.n)
        self._geo: PreviewModel | None = None

    def step(self, cancel: Callable[[], bool] | None = None) -> bool:
        """Do the next unit of work; True once the model is ready."""
        if self.model is not None:
            return True
        p, s = self.poser, len(self.codes)
        if self.done == 0:
            ref = p.offsets(self.reference, cancel=cancel)
            if ref is None:
                return False
            self._ref, self._scale = ref, _block_scales(p, self.codes, ref)
        elif self.done <= s:
            d = self._change(self.codes[self.done - 1], cancel)
            if d is None:
                return False
            self._sens += d.square().sum(1)
        elif self.done == s + 1:
            self._sens /= max(1, s)
            means = p.canonical["means"].cpu().numpy()
            self._geo = PreviewModel.geometric(means, self.n_probes, self.k, self.seed, self._sens.numpy())
            kk = self._geo.neighbours.shape[1]
            self._a, self._b = torch.zeros(p.n, kk, kk), torch.zeros(p.n, kk)
        else:
            d = self._change(self.codes[self.done - s - 2], cancel)
            if d is None:
                return False
            self._accumulate(d)
        self.done += 1
        if self.done == self.total:
            self._solve()
            return True
        return False

    def _change(self, z: np.ndarray, cancel: Callable[[], bool] | None) -> torch.Tensor | None:
        o = self.poser.offsets(z, cancel=cancel)
        return None if o is None else o.sub_(self._ref).mul_(self._scale)

    def _accumulate(self, d: torch.Tensor) -> None:
        """Add one code's normal equations: A_i += G_i G_i^T, b_i += G_i d_i with G_i the (K, width) changes
        of Gaussian i's probes."""
        geo = self._geo
        assert geo is not None
        idx = torch.from_numpy(geo.neighbours)
        dp = d.index_select(0, torch.from_numpy(geo.probes))
        for s in range(0, self.poser.n, 16384):
            e = min(self.poser.n, s + 16384)
            g = dp[idx[s:e]]  # (m, K, width)
            self._a[s:e].baddbmm_(g, g.transpose(1, 2))
            self._b[s:e].add_(torch.bmm(g, d[s:e, :, None])[..., 0])

    def _solve(self) -> None:
        """Ridge solution per Gaussian, pulled towards the geometric weights."""
        geo, a, b = self._geo, self._a, self._b
        assert geo is not None
        w0 = torch.from_numpy(geo.weights)
        lam = self.ridge * a.diagonal(dim1=1, dim2=2).mean(1).clamp_min(1e-12)
        w = torch.linalg.solve(a + lam[:, None, None] * torch.eye(a.shape[1]), b + lam[:, None] * w0)
        geo.weights = torch.where(torch.isfinite(w), w, w0).numpy().astype(np.float32)
        geo.fitted_codes = len(self.codes)
        geo._pin_probes()
        self.model = geo
        self._a = self._b = self._ref = torch.empty(0)


def _draw_probes(n: int, count: int, rng: np.random.Generator, sensitivity: np.ndarray | None) -> np.ndarray:
    """`count` distinct rows; with a sensitivity, drawn with probability ~ sqrt(s) + its mean (Gumbel top-k)."""
    if sensitivity is None:
        return np.sort(rng.choice(n, count, replace=False)).astype(np.int64)
    root = np.sqrt(np.maximum(np.asarray(sensitivity, np.float64), 0.0))
    p = root + root.mean() + 1e-30
    keys = np.log(p) - np.log(-np.log(rng.uniform(1e-12, 1.0, n)))
    return np.sort(np.argpartition(-keys, count - 1)[:count]).astype(np.int64)


def _block_scales(poser: FastPoser, codes: np.ndarray, ref: torch.Tensor, rows: int = 4096) -> torch.Tensor:
    """Per-column weights giving every offset block (F.position, G.sh, ...) the same total say in the fit."""
    rng = np.random.default_rng(1)
    sub = poser.subset(np.sort(rng.choice(poser.n, min(rows, poser.n), replace=False)))
    ref_sub = ref.index_select(0, torch.from_numpy(sub.index))
    var = torch.zeros(poser.layout.width)
    for z in codes:
        var += (cast(torch.Tensor, poser.offsets(z, rows=sub)) - ref_sub).square().mean(0)
    scale = torch.ones(poser.layout.width)
    for c, w in poser.layout.blocks.values():
        v = float(var[c : c + w].sum()) / max(1, len(codes))
        scale[c : c + w] = 1.0 / np.sqrt(max(v, 1e-30))
    return scale


_BF16_SPEEDUP: float | None = None


def bf16_speedup() -> float:
    """How many times faster this CPU multiplies bfloat16 than float32 matrices (measured once per process).

    Far above 1 with AMX or AVX512-BF16, far below 1 without (about 0.002 on AVX2 CPUs).
    """
    global _BF16_SPEEDUP
    if _BF16_SPEEDUP is None:
        times = {}
        for dtype in (torch.float32, torch.bfloat16):
            a, b = torch.randn(256, 256).to(dtype), torch.randn(256, 256).to(dtype)
            best = float("inf")
            for i in range(8):
                t0 = time.perf_counter()
                torch.mm(a, b)
                if i >= 2:  # after warming up
                    best = min(best, time.perf_counter() - t0)
            times[dtype] = best
        _BF16_SPEEDUP = times[torch.float32] / max(times[torch.bfloat16], 1e-9)
    return _BF16_SPEEDUP


class ProbeNets:
    """F and G on the probe rows, in float32 or in bfloat16 where this CPU multiplies it faster.

    `precision`: "fp32", "bf16", or "auto" (bf16 when `bf16_speedup()` >= 1.5). Low precision only feeds the
    preview, whose error the bench measures; exact poses are always float32.
    """

    def __init__(self, poser: FastPoser, probes: np.ndarray, precision: str = "auto"):
        self.rows = poser.subset(probes)
        # the bf16 chain runs every network on every probe, without skip layers
        plain = not any(n.config.skips for n in poser.nets.values()) and not self.rows.spans
        if precision == "auto":
            precision = "bf16" if poser.device.type == "cpu" and plain and bf16_speedup() >= 1.5 else "fp32"
        if precision == "bf16" and not plain:
            raise ValueError("bf16 probes need networks without skip layers that reach every probe")
        if precision not in ("fp32", "bf16"):
            raise ValueError(f"precision must be 'auto', 'fp32' or 'bf16', got {precision!r}")
        self.poser, self.precision = poser, precision
        self._layers = {}
        if precision == "bf16":
            for key, chain in poser.chains.items():
                self._layers[key] = ([w.to(torch.bfloat16) for w in chain.weights],
                                     [b.to(torch.bfloat16) for b in chain.biases], chain.relu, chain.act,
                                     poser.nets[key].output_act)

    @property
    def n(self) -> int:
        return self.rows.n

    @torch.no_grad()
    def offsets(self, z: np.ndarray, out: torch.Tensor) -> torch.Tensor:
        """Combined offsets (P, width) of the probes at z into `out`."""
        if self.precision == "fp32":
            return cast(torch.Tensor, self.poser.offsets(z, out=out, rows=self.rows))  # None only when cancelled
        terms = self.poser.code_terms(z)
        first = cast(dict[str, torch.Tensor], self.rows.first)
        step = self.poser.chunk_for(self.n)

        def body(lane: Lane, s: int) -> None:
            e = min(self.n, s + step)
            out[s:e].zero_()
            for key in self.poser.nets:
                weights, biases, relu, act, out_act = self._layers[key]
                h = (first[key][s:e] + terms[key][0]).to(torch.bfloat16)
                for i in range(len(weights)):
                    if i:
                        h = torch.addmm(biases[i], h, weights[i])
                    if i < len(weights) - 1:
                        h = h.clamp_min_(0.0) if relu else act(h)
                h = h.float()
                self.poser.route(key, h if out_act is None else out_act(h), self.rows, s, e, out[s:e])

        self.poser.parallel(list(range(0, self.n, step)), body)
        return out


class Previewer:
    """Writes preview posed clouds into caller arrays; holds the exact base offsets it corrects.

    The spreading is a sparse (N x P) matrix with K entries per row times the (P, width) probe changes,
    done per chunk of rows (scipy CSR) and followed at once by `FastPoser.apply_rows` on the same rows.
    """

    def __init__(self, poser: FastPoser, model: PreviewModel, chunk: int = 16384, precision: str = "auto"):
        n, k = model.neighbours.shape
        if n != poser.n:
            raise ValueError(f"preview model has {n} rows, the avatar {poser.n}")
        self.poser, self.model, self.chunk = poser, model, chunk
        self.probe_nets = ProbeNets(poser, model.probes, precision)
        self._probes = torch.from_numpy(model.probes)
        cols = model.neighbours.astype(np.int32)
        self._blocks = []
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            ptr = np.arange(0, (e - s) * k + 1, k, dtype=np.int32)
            self._blocks.append(csr_matrix((model.weights[s:e].ravel(), cols[s:e].ravel(), ptr),
                                           shape=(e - s, model.n_probes)))
        self._delta = torch.empty(model.n_probes, poser.layout.width)
        self._rows = [torch.empty(chunk, poser.layout.width) for _ in range(poser.threads)]
        self.base_code: np.ndarray | None = None
        self.base: torch.Tensor | None = None  # (N, width) exact offsets at base_code
        self._base_probes = torch.empty(0)

    @property
    def precision(self) -> str:
        return self.probe_nets.precision

    def set_base(self, code: np.ndarray, offsets: torch.Tensor) -> None:
        """The exact offsets (N, width) at `code`, which previews correct (kept by reference).

        The probes' own base is evaluated at the same precision as their previews, so that a systematic
        low-precision error cancels in the change."""
        self.base_code = np.asarray(code, np.float32).copy()
        self.base = offsets
        if self.precision == "fp32":
            self._base_probes = offsets.index_select(0, self._probes)
        else:
            self._base_probes = self.probe_nets.offsets(code, torch.empty(len(self._probes), offsets.shape[1]))

    @property
    def ready(self) -> bool:
        return self.base is not None

    @torch.no_grad()
    def offsets(self, z: np.ndarray) -> torch.Tensor:
        """The preview's combined offsets (N, width) at z (`pose_into` applies them chunk by chunk instead)."""
        if self.base is None:
            raise RuntimeError("the previewer has no exact base yet")
        delta = (self.probe_nets.offsets(z, torch.empty_like(self._delta)) - self._base_probes).numpy()
        return self.base + torch.cat([torch.from_numpy(b @ delta) for b in self._blocks])

    @torch.no_grad()
    def pose_into(self, z: np.ndarray, dest: dict[str, np.ndarray], timings: dict[str, float] | None = None) -> None:
        """Preview posed cloud at z into `dest` (arrays shaped as `PosedGaussians`)."""
        if self.base is None:
            raise RuntimeError("the previewer has no exact base yet")
        t0 = time.perf_counter()
        self.probe_nets.offsets(z, self._delta)
        delta = self._delta.sub_(self._base_probes).numpy()
        t1 = time.perf_counter()
        out = {k: torch.from_numpy(v) for k, v in dest.items() if v is not None}
        base = self.base

        def body(lane: Lane, i: int) -> None:
            block = self._blocks[i]
            s = i * self.chunk
            e = s + block.shape[0]
            rows = self._rows[lane.index][: e - s]
            torch.add(base[s:e], torch.from_numpy(block @ delta), out=rows)
            self.poser.apply_rows(rows, s, e, out)

        self.poser.parallel(list(range(len(self._blocks))), body)
        if timings is not None:
            timings["probes"] = (t1 - t0) * 1e3
            timings["spread_apply"] = (time.perf_counter() - t1) * 1e3
