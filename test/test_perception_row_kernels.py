"""The compiled feature rows (row_kernels.clipped_features) are detections.as_features clipped, column for column."""
import numpy as np

from dynenv_ros.perception.detections import DETECTION_DTYPE, FEATURE_COLUMNS, as_features
from dynenv_ros.perception.row_kernels import clipped_features


def _random_rows(rng, count):
    rows = np.zeros(count, DETECTION_DTYPE)
    for name in DETECTION_DTYPE.names:
        kind = DETECTION_DTYPE[name].kind
        if kind == "f":
            rows[name] = rng.normal(0.0, 40.0, count)        # beyond the bound now and then
        elif kind == "b":
            rows[name] = rng.random(count) < 0.5
        else:
            info = np.iinfo(DETECTION_DTYPE[name])
            rows[name] = rng.integers(max(info.min, -128), min(info.max, 255) + 1, count)
    rows["yaw"][rng.random(count) < 0.3] = np.nan                 # undefined headings
    return rows


def test_clipped_features_equal_as_features_clipped():
    rng = np.random.default_rng(7)
    bound = 50.0
    rows = _random_rows(rng, 2000)
    expected = np.clip(as_features(rows), -bound, bound)
    got = clipped_features(rows, bound)
    assert got.dtype == np.float32 and got.shape == (2000, len(FEATURE_COLUMNS))
    trig = [FEATURE_COLUMNS.index("cos_yaw"), FEATURE_COLUMNS.index("sin_yaw")]
    other = [k for k in range(len(FEATURE_COLUMNS)) if k not in trig]
    np.testing.assert_array_equal(got[:, other], expected[:, other])
    # cos/sin: float64 rounded against numpy's float32 functions, at most one float32 ulp apart
    np.testing.assert_array_max_ulp(got[:, trig], expected[:, trig], maxulp=1)
    assert (np.abs(got) <= bound).all() and (got[:, other] == bound).any() and (got[:, other] == -bound).any()
    assert clipped_features(rows[:0], bound).shape == (0, len(FEATURE_COLUMNS))
