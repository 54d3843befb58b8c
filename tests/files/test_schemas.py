"""Declared schemas (npga_core/schema.py): every JSON-like input refused with one line naming the file and the field
path of the problem: sessions, keyframes, presets, rigs, .npga header sections, ARKit JSON takes, glTF metadata;
and the one number checker (strict: no "3" for 3, no true for 1, no NaN)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from npga_core.editing.keyframes import KeyframeTimeline
from npga_core.errors import AvatarFileError
from npga_core.files.arkit_takes import read_arkit_json
from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.files.rig import load_rig
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.schema import SchemaError, decode, number
from npga_view.controllers.actions import read_presets
from npga_view.state import Timeline, ViewerState
from tests.support.npga_files import split_npga, write_npga


def _one_line(path: Path, err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    return text.removeprefix(f"{path}: ")


@pytest.mark.parametrize("number_value, kw, problem", [
    (True, {}, "n: expected a number, got a boolean"),
    ("3", {}, "n: expected a number, got a string"),
    (math.nan, {}, "n: expected a finite number"),
    (-math.inf, {}, "n: expected a finite number"),
    (11, {"hi": 10}, "n: expected a number <= 10, got 11"),
    (2.5, {"whole": True}, "n: expected an integer, got a number"),
    (10**50, {"whole": True, "hi": 10}, "n: expected an integer <= 10, got an integer of 167 bits"),
])
def test_the_one_number_checker_is_strict(number_value, kw, problem):
    with pytest.raises(SchemaError) as e:
        number(number_value, "n", **kw)
    assert str(e.value) == problem


def test_number_accepts_what_it_should():
    assert number(3, "n") == 3.0 and number(2.0, "n", whole=True) == 2 and number(-1e300, "n") == -1e300


def test_decode_names_the_path_and_never_coerces():
    schema = dict[str, list[tuple[int, float]]]
    assert decode({"a": [[1, 2]]}, schema) == {"a": [(1, 2.0)]}
    with pytest.raises(SchemaError, match=r"^x\[\.\.\.\]\[0\]\[0\]: expected an integer, got a string$"):
        decode({"a": [["1", 2.0]]}, schema, "x")


@pytest.mark.parametrize("session, problem", [
    ({"camera": {"fov_y": 400}}, "camera.fov_y: expected a number <= 170, got 400"),
    ({"camera": {"target": [0, 0]}}, "camera.target: expected a list of length 3, got 2"),
    ({"sliders": [0.0, "x"]}, "sliders[1]: expected a number, got a string"),
    ({"timeline": {"speed": True}}, "timeline.speed: expected a number, got a boolean"),
    ({"avatar": "a\u0000b"}, "avatar: expected a path without NUL bytes"),
    ({"background": [0, 2, 0]}, "background[1]: expected a number <= 1, got 2"),
    ({"rig_index": 10**20}, "rig_index: expected a number <= 4096"),
])
def test_session_problems_name_the_field(tmp_path, session, problem):
    path = tmp_path / "session.json"
    path.write_text(json.dumps({"npga_view_session": 1, **session}))
    state = ViewerState()
    with pytest.raises(AvatarFileError) as e:
        state.load_session(path)
    assert _one_line(path, e).startswith(problem)


def test_a_session_round_trips_and_unknown_fields_are_ignored(tmp_path):
    """Every field of a session (each timeline setting changed from its default, so that a setting the schema
    lacks would be lost) comes back; a field from a newer version is ignored."""
    state = ViewerState()
    state.camera.yaw, state.background, state.mode = 30.0, (0.1, 0.2, 0.3), "depth"
    state.sliders = np.array([0.5, -1.0], np.float32)
    for f in dataclasses.fields(Timeline):
        v = getattr(state.timeline, f.name)
        setattr(state.timeline, f.name, (not v) if isinstance(v, bool) else v + 0.25 if isinstance(v, float)
                else "exponential")
    path = tmp_path / "s.json"
    path.write_text(json.dumps({**state.to_session(), "from_the_future": [1, 2]}))
    back = ViewerState()
    back.load_session(path)
    assert back.to_session() == state.to_session() and not back.timeline.playing


@pytest.mark.parametrize("keys, problem", [
    ([{"time": 0, "code": [1]}, {"time": 1e9, "code": [1]}], "expression[1].time: expected a number <= 86400"),
    ([{"time": 0, "code": [1, True]}], "expression[0].code[1]: expected a number, got a boolean"),
    ([{"time": 0, "code": [1], "ease_in": 2}], "expression[0].ease_in: expected a number <= 1, got 2"),
    ([{"time": 0, "code": [1], "label": 7}], "expression[0].label: expected a string, got an integer"),
    ([{"code": [1]}], "expression[0]: object missing required field `time`"),
])
def test_keyframe_problems_name_the_key_and_field(tmp_path, keys, problem):
    path = tmp_path / "keys.json"
    path.write_text(json.dumps({"npga_keyframes": 1, "expression": keys}))
    with pytest.raises(AvatarFileError) as e:
        KeyframeTimeline.load(path)
    assert _one_line(path, e).startswith(problem)


@pytest.mark.parametrize("presets, problem", [
    ({"smile": [0.0, "1"]}, "presets['smile'][1]: expected a number, got a string"),
    ({"smile": []}, "presets['smile']: expected a list of length >= 1"),
    ([1, 2], "expected an object, got a list"),
])
def test_preset_problems_name_the_preset(tmp_path, presets, problem):
    path = tmp_path / "presets.json"
    path.write_text(json.dumps(presets))
    with pytest.raises(AvatarFileError) as e:
        read_presets(path)
    assert _one_line(path, e) == problem


def test_presets_read_as_written(tmp_path):
    path = tmp_path / "presets.json"
    path.write_text(json.dumps({"smile": [0.0, 1, -2.5]}))
    assert read_presets(path) == {"smile": [0.0, 1.0, -2.5]}


@pytest.mark.parametrize("change, problem", [
    ({"world_2_cam": {"A": np.eye(4)[:3].tolist()}}, "world_2_cam['A']: expected a list of length 4, got 3"),
    ({"intrinsics": [[1, 0, 0], [0, "f", 0], [0, 0, 1]]}, "intrinsics[1][1]: expected a number, got a string"),
    ({"image_size": [512, True]}, "image_size[1]: expected a number, got a boolean"),
])
def test_rig_problems_name_the_field(tmp_path, change, problem):
    rig = {"world_2_cam": {"A": np.eye(4).tolist()}, "intrinsics": [[800, 0, 256], [0, 800, 256], [0, 0, 1]],
           **change}
    path = tmp_path / "camera_params.json"
    path.write_text(json.dumps(rig))
    with pytest.raises(AvatarFileError) as e:
        load_rig(path)
    assert _one_line(path, e).startswith(problem)


@pytest.fixture(scope="module")
def npga(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("schemas") / "a.npga"
    save_avatar(make_synthetic_avatar(50, hidden=8, depth=2, code_dim=4, n_components=2, with_cnn=True,
                                      latent_dim=4, seed=3), path)
    return path


def _gaussians(h: dict) -> None:
    h["gaussians"]["count"] = "50"


def _offset(h: dict) -> None:
    h["tensors"]["gaussians.means"]["offset"] = -64


def _hidden(h: dict) -> None:
    h["dynamics"]["F"]["hidden"] = 8.5


def _kernel(h: dict) -> None:
    h["cnn"] = {"residual": True, "ops": [{"op": "conv", "in": 7, "out": 3, "kernel": "3"}]}


def _op(h: dict) -> None:
    h["cnn"] = {"residual": True, "ops": [{"op": "dance"}]}


def _units(h: dict) -> None:
    h["units"] = ["m"]


@pytest.mark.parametrize("mutate, problem", [
    (_gaussians, "gaussians.count: expected an integer, got a string"),
    (_offset, "tensors['gaussians.means'].offset: expected an integer >= 0, got -64"),
    (_hidden, "dynamics.F.hidden: expected an integer, got a number"),
    (_kernel, "cnn.ops[0].kernel: expected an integer, got a string"),
    (_op, "cnn.ops[0].op: invalid value 'dance'"),
    (_units, "units: expected a string, got a list"),
])
def test_npga_header_problems_name_the_field(npga, tmp_path, mutate, problem):
    header, data = split_npga(npga)
    mutate(header)
    path = write_npga(tmp_path / "bad.npga", header, data)
    with pytest.raises(AvatarFileError) as e:
        read_avatar(path)
    assert _one_line(path, e).lower().startswith(problem.lower())


@pytest.mark.parametrize("doc, problem", [
    ({"names": ["jawOpen"], "frames": [{"weights": [0.1]}, {"weights": [0.1, 0.2]}]},
     "frames[1].weights: expected 1 values (one per name), got 2"),
    ({"names": ["jawOpen"], "metadata": {"fps": 0}, "frames": []}, "metadata.fps: expected a number >= 0.001, got 0"),
    ({"frames": [{"time": 0, "blendshapes": {"jawOpen": "x"}}]},
     "frames[0].blendshapes[...]: expected a number, got a string"),
    ([[{"categoryName": "jawOpen", "score": None}]], "[0][0].score: expected a number, got null"),
    ({"facsNames": ["jawOpen", 5], "weightMat": []}, "facsNames[1]: expected a string, got an integer"),
])
def test_take_json_problems_name_the_field(tmp_path, doc, problem):
    path = tmp_path / "take.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(AvatarFileError) as e:
        read_arkit_json(path)
    assert _one_line(path, e).startswith(problem)


def test_gltf_metadata_problems_name_the_field():
    pygltflib = pytest.importorskip("pygltflib")
    from npga_core.files.gltf_arrays import GltfArrays, GltfError

    g = pygltflib.GLTF2(nodes=[pygltflib.Node(name="head"), pygltflib.Node(mesh=-1, skin=0)])
    with pytest.raises(GltfError, match=r"^nodes\[1\]\.mesh: expected an integer >= 0, got -1$"):
        GltfArrays(g)
    g = pygltflib.GLTF2(nodes=[pygltflib.Node(translation=[0.0, float("nan"), 0.0])])
    with pytest.raises(GltfError, match=r"^nodes\[0\]\.translation\[1\]: expected a finite number$"):
        GltfArrays(g)
    g = pygltflib.GLTF2(meshes=[pygltflib.Mesh(extras={"targetNames": ["a", ""]})])
    with pytest.raises(GltfError, match=r"^meshes\[0\]\.extras\.targetNames\[1\]: expected a string of length >= 1"):
        GltfArrays(g)
