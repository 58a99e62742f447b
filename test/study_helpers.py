"""What every study's JSON must hold per filter (issue 13's schema)."""
import numpy as np


def assert_filter_schema(filters: dict, duration: float) -> None:
    """``final_error_deg`` mean and rmse (E, N, U, finite), ``cpu_s`` > 0, the alignment
    times None (never) or within the run."""
    for name, r in filters.items():
        for k in ("mean", "rmse"):
            assert len(r["final_error_deg"][k]) == 3, name
            assert all(np.isfinite(r["final_error_deg"][k])), name
        assert r["cpu_s"] > 0, name
        for k in ("time_to_level_s", "time_to_heading_s"):
            assert r[k] is None or 0 <= r[k] <= duration, (name, k, r[k])
