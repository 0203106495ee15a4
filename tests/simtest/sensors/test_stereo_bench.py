"""The stereo cost benchmark runs on a small generated scene and reports sane numbers."""

from simtest.benchmarks.stereo import run, table


def test_stereo_benchmark_small():
    result = run(160, 120, repeat=1, views=1)
    assert set(result) == {"frame_ms", "stereo_ms", "ratio", "valid", "passes_ms", "sgbm_ms", "other_ms"}
    assert result["stereo_ms"] > 0 and result["frame_ms"] > 0 and 0.3 < result["valid"] <= 1.0
    assert result["passes_ms"] > 0 and result["sgbm_ms"] > 0 and result["other_ms"] >= 0
    assert "stereo" in table(result) and "SGBM" in table(result)
