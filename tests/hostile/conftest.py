"""The hostile-file tests' shared world: one fork server (tests/support/cli_forkserver.py) and valid files to
tamper with, for test_hostile_files.py and test_hostile_outputs.py."""

from __future__ import annotations

import pytest

from tests.support.hostile_readers_corpus import GHA_SMALL


@pytest.fixture(scope="session")
def world(tmp_path_factory):
    """A small animatable avatar, a PLY, valid caches to tamper with, and the fork server."""
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.ply import save_ply
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_core.posing.bake import BakeStore
    from npga_core.posing.preview import PreviewModel

    root = tmp_path_factory.mktemp("hostile")
    avatar = make_synthetic_avatar(400, seed=7)
    npga = root / "avatar.npga"
    save_avatar(avatar, npga)
    ply = root / "static.ply"
    save_ply(make_synthetic_avatar(50, with_f=False, with_g=False).cloud, ply)
    store = BakeStore.create("k" * 32, 6, 400, 10, 8)
    store.done[:] = True
    bake = root / "good.npgabake"
    store.save(bake)
    model = PreviewModel.geometric(avatar.cloud.means, 64, 4)
    model.key = "k" * 32
    preview = root / "good-preview.npz"
    model.save(preview)
    from npga_core.files.gha_synthetic import gha_state_dicts

    gha_head, gha_sr = gha_state_dicts(120, 0, **GHA_SMALL)
    gha = root / "gha"
    gha.mkdir()
    import torch

    torch.save(gha_head, gha / "gaussianhead_latest")
    from npga_core.files.gha import import_gha

    v2 = root / "gha.npga"
    save_avatar(import_gha(gha), v2)
    shrink = root / "shrink"
    shrink.mkdir()
    from tests.support.cli_forkserver import ForkServer

    server = ForkServer(root, env={"DISPLAY": "", "WAYLAND_DISPLAY": "", "XDG_CONFIG_HOME": str(root / "cfg"),
                                   "XDG_CACHE_HOME": str(root / "cache")})
    yield {"root": root, "avatar": npga, "dim": avatar.code_dim, "n": len(avatar), "ply": ply, "bake": bake,
           "preview": preview, "key": "k" * 32, "server": server, "gha": gha, "gha_head": gha_head,
           "gha_supres": gha_sr, "v2": v2}
    server.close()
