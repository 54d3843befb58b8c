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
    assert avg["splats"] >= 20.0 and avg["posing"] == 0.0
    first, sections = p.lines()  # the work and the wait for input apart, then the work section by section
    assert first == f"UI frame {sum(avg.values()) - avg['wait']:.1f} ms + {avg['wait']:.1f} ms waiting for input"
    assert "splats " in sections and sections.index("panels") < sections.index("splats") and "wait" not in sections
    assert max(len(first), len(sections)) <= 60  # no wider than the overlay's other lines


def test_only_recent_frames_count():
    p = FrameProfile(window_s=0.05)
    assert p.averages() == {} and p.lines() == []
    p.start()
    time.sleep(0.03)
    p.mark("posing")
    p.end()
    time.sleep(0.1)
    p.start()
    p.mark("posing")
    p.end()  # the first frame is older than the window now: only the last one counts
    assert p.averages()["posing"] == p.last["posing"]
