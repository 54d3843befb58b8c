"""`FrameProfile` (npga_view/frame_profile.py): the window's UI frames split into sections."""

import time

from npga_view.frame_profile import SECTIONS, FrameProfile


def test_sections_take_the_time_between_marks():
    p = FrameProfile(window_s=60.0)
    for _ in range(2):
        p.start()
        time.sleep(0.01)
        p.mark("wait")
        p.mark("panels")
        time.sleep(0.02)
        p.mark("splats")
        p.mark("splats")  # a section marked twice adds up
        p.end()
    assert set(p.last) == {"wait", "panels", "splats"}
    assert p.last["splats"] >= 20.0 and p.last["wait"] >= 10.0 and p.last["panels"] < p.last["splats"]
    avg = p.averages()
    assert list(avg) == list(SECTIONS)  # every section, in frame order; unmarked ones 0
    assert avg["splats"] >= 20.0 and avg["dynamics"] == 0.0
    line = p.line()  # the work, section by section, then the wait for input apart
    assert line.startswith("UI frame ") and "splats " in line and line.index("panels") < line.index("splats")
    assert line.endswith(f"(+ waiting for input {avg['wait']:.1f})")
    work = float(line.split(" ms:")[0].split()[-1])
    assert abs(work - (sum(avg.values()) - avg["wait"])) < 0.06


def test_only_recent_frames_count():
    p = FrameProfile(window_s=0.05)
    assert p.averages() == {} and p.line() == ""
    p.start()
    time.sleep(0.03)
    p.mark("dynamics")
    p.end()
    time.sleep(0.1)
    p.start()
    p.mark("dynamics")
    p.end()  # the first frame is older than the window now
    assert p.averages()["dynamics"] < 30.0
