"""Decoding speed of the other protocols' decoders, against named peers, on the same bytes.

- Xsens MTData2: the station's ``XsensDecoder`` against the rate an MTi-600 can output
  (2000 Hz of RateOfTurnHR/AccelerationHR: the real-time need) and against the native decoder.
- MAVLink: the station's ``MavlinkDecoder`` (own resyncing framing, pymavlink payloads) against
  pymavlink's own ``MAVLink.parse_buffer`` on the same HIGHRES_IMU stream.
- CSV lines: the station's ``AsciiDecoder`` against ``numpy.loadtxt`` on the same lines.
- Auto-detection: time to recognise each protocol from its first 4 KB.

Every stream is fed in 4 KB chunks, as the reader thread does. Medians of repeats; the machine
is shared.

    .venv/bin/python benchmarks/bench_protocols.py [--samples N] [--repeats R]
"""

from __future__ import annotations

import argparse
import io

import numpy as np
from timing import feed_in_chunks, median_time

from protocols import ascii_lines, mavlink, native, xsens
from protocols.base import SAMPLE_DTYPE
from protocols.detect import detect

CHUNK = 4096


def make_samples(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.arange(n) * 1000
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0
    return s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    n, repeats = args.samples, args.repeats
    s = make_samples(n)

    def rate(seconds: float) -> float:
        return n / seconds

    native_bytes = native.encode_samples(s)
    t_native = median_time(feed_in_chunks(native.NativeDecoder, native_bytes, CHUNK), repeats)
    print(f"{n} samples, {repeats} repeats, {CHUNK}-byte chunks (medians)")
    print(f"native decoder                 {rate(t_native):12,.0f} samples/s")

    xsens_bytes = xsens.encode_samples(s)
    t_xsens = median_time(feed_in_chunks(xsens.XsensDecoder, xsens_bytes, CHUNK), repeats)
    print(f"xsens decoder (float32)        {rate(t_xsens):12,.0f} samples/s   "
          f"{rate(t_xsens) / 2000:6.1f}x an MTi-600 at 2000 Hz, {t_xsens / t_native:6.1f}x native's time")
    fp_bytes = xsens.encode_samples(s, precision="fp1632")
    t_fp = median_time(feed_in_chunks(xsens.XsensDecoder, fp_bytes, CHUNK), repeats)
    print(f"xsens decoder (fp1632)         {rate(t_fp):12,.0f} samples/s   "
          f"{rate(t_fp) / 2000:6.1f}x an MTi-600")

    if mavlink.pymavlink_available():
        from pymavlink.dialects.v20 import ardupilotmega

        mav_bytes = mavlink.encode_samples(s, "HIGHRES_IMU")
        t_ours = median_time(feed_in_chunks(mavlink.MavlinkDecoder, mav_bytes, CHUNK), repeats)

        def pymavlink_parse() -> int:
            mav = ardupilotmega.MAVLink(None)
            mav.robust_parsing = True
            count = 0
            for pos in range(0, len(mav_bytes), CHUNK):
                count += len(mav.parse_buffer(mav_bytes[pos : pos + CHUNK]) or [])
            return count

        t_peer = median_time(pymavlink_parse, repeats)
        print(f"mavlink decoder (HIGHRES_IMU)  {rate(t_ours):12,.0f} samples/s   "
              f"pymavlink parse_buffer {rate(t_peer):,.0f}/s: ratio {t_peer / t_ours:.2f} (>1: ours faster)")
    else:
        print("mavlink: pymavlink is not installed, skipped")

    csv_bytes = ascii_lines.encode_csv(s)
    t_csv = median_time(feed_in_chunks(ascii_lines.AsciiDecoder, csv_bytes, CHUNK), repeats)
    t_loadtxt = median_time(lambda: np.loadtxt(io.BytesIO(csv_bytes), delimiter=","), repeats)
    print(f"ascii decoder (CSV lines)      {rate(t_csv):12,.0f} samples/s   "
          f"numpy.loadtxt {rate(t_loadtxt):,.0f}/s: ratio {t_loadtxt / t_csv:.2f} (>1: ours faster)")
    vn_bytes = ascii_lines.encode_samples(s, "vnymr")
    t_vn = median_time(feed_in_chunks(ascii_lines.AsciiDecoder, vn_bytes, CHUNK), repeats)
    print(f"ascii decoder ($VNYMR)         {rate(t_vn):12,.0f} samples/s")

    streams = {"native": native_bytes, "xsens": xsens_bytes, "ascii": csv_bytes}
    if mavlink.pymavlink_available():
        streams["mavlink"] = mav_bytes
    for name, data in streams.items():
        t_detect = median_time(lambda data=data: detect(data[:4096]), repeats)
        print(f"detect {name:<8} from 4 KB      {t_detect * 1e3:9.2f} ms")


if __name__ == "__main__":
    main()
