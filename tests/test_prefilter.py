import numpy as np
import pytest
from scipy import signal

from gyrodiag.common.prefilter import ButterworthPrefilter


def test_streaming_equals_sosfilt_on_whole_record():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((3000, 4))
    filt = ButterworthPrefilter(order=6, cutoff_hz=50.0, sample_rate_hz=1000.0, n_channels=4)
    streamed = np.array([filt.update(row) for row in x])
    reference = signal.sosfilt(filt.sos, x, axis=0)
    np.testing.assert_allclose(streamed, reference, rtol=0, atol=1e-12)


def test_record_split_in_chunks_equals_sample_by_sample():
    rng = np.random.default_rng(2)
    x = rng.standard_normal((1000, 2))
    a = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=2)
    b = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=2)
    chunks = np.vstack([a.update(x[:333]), a.update(x[333:334]), a.update(x[334:])])
    single = np.array([b.update(r) for r in x])
    np.testing.assert_allclose(chunks, single, rtol=0, atol=1e-12)


def test_cutoff_gain_is_minus_3db_and_channels_are_identical():
    filt = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=3)
    _, h = signal.sosfreqz(filt.sos, worN=[50.0], fs=1000.0)
    assert abs(abs(h[0]) - 1 / np.sqrt(2)) < 1e-9
    y = filt.update(np.ones((500, 3)))
    assert np.all(y[:, 0] == y[:, 1]) and np.all(y[:, 1] == y[:, 2])
    assert abs(y[-1, 0] - 1.0) < 1e-6  # unit DC gain


def test_state_round_trip_and_reset():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((400, 1))
    f = ButterworthPrefilter(4, 20.0, 1000.0)
    f.update(x[:200])
    saved = f.get_state()
    first = f.update(x[200:])
    f.set_state(saved)
    np.testing.assert_array_equal(f.update(x[200:]), first)
    f.reset()
    fresh = ButterworthPrefilter(4, 20.0, 1000.0)
    np.testing.assert_array_equal(f.update(x), fresh.update(x))


def test_nan_input_raises_and_leaves_state_untouched():
    f = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=2)
    f.update([1.0, 2.0])
    before = f.get_state()["zi"]
    with pytest.raises(ValueError, match="x must contain only finite"):
        f.update([np.nan, 0.0])
    np.testing.assert_array_equal(f.get_state()["zi"], before)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"order": 0, "cutoff_hz": 50.0, "sample_rate_hz": 1000.0}, "order"),
        ({"order": 6, "cutoff_hz": 600.0, "sample_rate_hz": 1000.0}, "cutoff_hz"),
        ({"order": 6, "cutoff_hz": 50.0, "sample_rate_hz": -1.0}, "sample_rate_hz"),
        ({"order": 6, "cutoff_hz": 50.0, "sample_rate_hz": 1000.0, "n_channels": 0},
         "n_channels"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs, name):
    with pytest.raises((ValueError, TypeError), match=name):
        ButterworthPrefilter(**kwargs)


def test_wrong_sample_shape_is_rejected():
    f = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=4)
    with pytest.raises(ValueError, match=r"shape \(4,\)"):
        f.update([1.0, 2.0])


def test_highpass_cascade_is_a_bandpass_and_streams_exactly():
    filt = ButterworthPrefilter(6, 50.0, 1000.0, n_channels=2, highpass_hz=2.0)
    assert filt.sos.shape == (4, 6)  # 3 low-pass sections + 1 high-pass section
    _, h = signal.sosfreqz(filt.sos, worN=[0.0, 2.0, 20.0, 50.0], fs=1000.0)
    assert abs(h[0]) < 1e-12  # no DC
    assert abs(abs(h[1]) - 1 / np.sqrt(2)) < 0.01  # -3 dB at the high-pass corner
    assert abs(abs(h[2]) - 1.0) < 0.02  # pass band
    rng = np.random.default_rng(5)
    x = rng.standard_normal((2000, 2))
    streamed = np.array([filt.update(r) for r in x])
    np.testing.assert_allclose(streamed, signal.sosfilt(filt.sos, x, axis=0), atol=1e-12)


def test_highpass_must_lie_below_the_lowpass():
    with pytest.raises(ValueError, match="highpass_hz must be below cutoff_hz"):
        ButterworthPrefilter(6, 50.0, 1000.0, highpass_hz=60.0)
