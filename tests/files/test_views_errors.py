"""`evaluation.views.load_view` refuses an image whose size is not its camera's with AvatarFileError naming the
file (it raised a TypeError: the error was built with one argument; found by mypy, #26)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.support.captures import capture_cameras, write_capture


def test_an_image_of_another_size_than_its_camera_is_refused_naming_it(tmp_path):
    from npga_core import load_avatar
    from npga_core.errors import AvatarFileError
    from npga_core.evaluation.capture import load_capture
    from npga_core.evaluation.views import load_view

    cams = capture_cameras(load_avatar("demo"))
    images = {s: (np.full((c.height, c.width, 3), 0.5), np.ones((c.height, c.width))) for s, c in cams.items()}
    write_capture(tmp_path, cams, images)
    capture = load_capture(tmp_path)
    view = next(iter(capture.views.values()))
    cam = view.camera
    cv2.imwrite(str(view.image_path), np.zeros((cam.height + 2, cam.width, 3), np.uint8))
    with pytest.raises(AvatarFileError, match="other than its camera's") as err:
        load_view(capture, view, "none")
    assert view.image_path.name in str(err.value)
