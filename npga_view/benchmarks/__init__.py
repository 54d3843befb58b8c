"""Benchmarks of the viewer on this machine: `npga-view bench` (`bench.py`: the dynamics, preview, playback,
drawing; `bench_precision.py`: gemm rates, fp32 vs bf16, points vs quads), the real window (`bench_window.py`)
and GaussianSplattingViewer's renderer beside ours (`bench_peer.py`). Not imported by the viewer itself."""
