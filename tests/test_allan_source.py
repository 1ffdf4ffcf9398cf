"""The Allan input stream: a record read twice (a capture file) gives the same sums on disk as a one-shot
stream, with dropped, repeated and missing samples; a non-finite sample is refused naming it."""

from __future__ import annotations

import numpy as np
import pytest

from station.acquisition.allan_source import capture_chunks, integrate_stream
from station.engines.allan import deviation as allan
from station.errors import EngineInputError


def _chunks(n: int = 30_000, seed: int = 4) -> list:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 200.0
    t[1000] = t[999]            # a repeated stamp
    t[2000] = t[1990]           # an older one
    t = np.delete(t, np.arange(5000, 5040))  # a gap
    y = np.cumsum(rng.standard_normal((len(t), 6)) * 1e-4, axis=0) + rng.standard_normal((len(t), 6)) * 0.01
    y[:, 5] += 9.81
    cuts = [0, 700, 1500, 9000, 21000, len(t)]
    return [(t[a:b], y[a:b, 3:], y[a:b, :3]) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]


def test_read_twice_gives_the_one_shot_sums(tmp_path) -> None:
    chunks = _chunks()
    with integrate_stream(iter(chunks), "once", workdir=tmp_path) as once, \
            integrate_stream(chunks, "twice", workdir=tmp_path) as twice:
        # the same sequential float64 sums, bit for bit, and the same account of the timestamps
        for a, b in zip(once.phase, twice.phase, strict=True):
            assert np.array_equal(a, b)
        assert once.timing.as_dict() == twice.timing.as_dict()
        # the two dropped stamps leave one-sample gaps beside the 40-sample one
        assert (twice.timing.duplicates, twice.timing.disordered, twice.timing.gaps) == (1, 1, 3)
        np.testing.assert_array_equal(once.means, twice.means)
        # and eq. (1) of the kept samples
        t = np.concatenate([c[0] for c in chunks])
        y = np.concatenate([np.column_stack([c[2], c[1]]) for c in chunks])
        keep = t > np.maximum.accumulate(np.concatenate([[-1.0], t]))[:-1]
        ref = allan.integrate_rates(y[keep], 200.0)
        np.testing.assert_allclose(np.array(twice.phase), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert list(tmp_path.iterdir()) == []


def test_capture_file_is_read_twice_in_its_own_float32(tmp_path) -> None:
    from protocols.base import SAMPLE_DTYPE
    from station.acquisition.capture_h5 import H5CaptureWriter

    rng = np.random.default_rng(8)
    samples = np.zeros(50_000, dtype=SAMPLE_DTYPE)
    samples["t_us"] = np.arange(len(samples)) * 5000
    samples["gyro"] = rng.standard_normal((len(samples), 3)) * 0.01
    samples["acc"] = rng.standard_normal((len(samples), 3)) * 0.02 + [0.0, 0.0, 9.81]
    path = tmp_path / "still.h5"
    writer = H5CaptureWriter(path, device={"serial": "H5-TWICE"})
    writer.write(samples)
    writer.close()
    chunks, device, _ = capture_chunks(path)
    assert iter(chunks) is not chunks and device["serial"] == "H5-TWICE"
    y = np.column_stack([samples["gyro"], samples["acc"]]).astype(np.float64)
    with integrate_stream(chunks, str(path), workdir=tmp_path) as rec:
        assert rec.rate_hz == 200.0 and rec.n_samples == len(samples)
        ref = allan.integrate_rates(y, 200.0)
        np.testing.assert_allclose(np.array(rec.phase), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("twice", [False, True])
def test_non_finite_sample_named(tmp_path, twice: bool) -> None:
    chunks = _chunks(8000)
    chunks[2][1][17, 1] = np.nan  # ay of the third chunk
    t_bad = chunks[2][0][17]
    with pytest.raises(EngineInputError, match=rf"t = {t_bad:.6f} s has a non-finite ay \(nan\)"):
        integrate_stream(chunks if twice else iter(chunks), "x.csv", workdir=tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("twice", [False, True])
def test_reading_error_raised_in_the_callers_thread(tmp_path, twice: bool) -> None:
    import threading

    from station.errors import InputFileError

    good = _chunks(8000)

    class Broken:
        """A source whose third chunk cannot be read (as a truncated file's), read twice or once."""

        def __iter__(self):
            yield from good[:2]
            raise InputFileError(tmp_path / "x.csv", "line 9000 is cut short", line=9000)

    with pytest.raises(InputFileError, match="line 9000 is cut short"):
        integrate_stream(Broken() if twice else iter(Broken()), "x.csv", workdir=tmp_path)
    assert list(tmp_path.iterdir()) == []
    # the read-ahead thread ended with the stream
    assert not [t for t in threading.enumerate() if t.name == "allan-read-ahead"]
