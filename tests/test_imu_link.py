"""The device-side C library, ``firmware/imu_link``: built, unit-tested, fuzzed, and put on a port.

The library compiles warning-free with gcc and, for a Cortex-M4, with arm-none-eabi-gcc (its code
size is printed); its C unit tests and the fuzzing of its parser run under AddressSanitizer and
UBSan; its parser finds the same frames as the station's decoder. The POSIX example device, built
from the library, serves a simulated unit on a pseudo-terminal, and the station talks to it as to a
real board: its frames are the station's encoding bit for bit, it answers every host command, the
device contract suite (``tests/test_contract.py --imu-port``) passes on it, ``imu-station capture``
then ``allan`` find its noise terms, and the TUI connects to it and shows it live.

Without gcc (or arm-none-eabi-gcc) the tests that need it skip, except in CI (``CI=true``), where
``.ci/run`` installs both and a missing compiler fails the run.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import serial
from tui_helpers import screen_text, wait_for

from drivers import CommandRejected, SerialDevice, open_device
from protocols import native
from protocols.base import Message, has_mag
from protocols.mag_batches import join_batches
from station.acquisition.capture_h5 import read_samples
from station.tui.app import StationApp
from station.tui.config import TuiConfig

ROOT = Path(__file__).resolve().parents[1]
LIB = ROOT / "firmware" / "imu_link"
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g", "-O1"]
CLI = [str(Path(sys.executable).with_name("imu-station"))]
G = 9.80665
# What the library may call: the spec allows <string.h> and nothing else of the C library.
ALLOWED_CALLS = {"memchr", "memcpy", "memmove", "memset", "strlen"}
CORTEX_M4 = ["-mcpu=cortex-m4", "-mthumb", "-Os"]
CODE_BUDGET = 4096  # bytes of flash the library may take on a Cortex-M4 at -Os
FUZZ_STREAMS = 4000


def tool(name: str) -> str:
    """The path of a compiler or binutil; skips without it, but fails in CI, which installs it."""
    path = shutil.which(name)
    if path is None:
        if os.environ.get("CI") == "true":
            pytest.fail(f"{name} is not installed: .ci/run installs it (Debian: gcc, gcc-arm-none-eabi)")
        pytest.skip(f"{name} is not installed")
    return path


def run(args: list[str], **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=120, **kw)


def compile_c(out: Path, sources: list[Path], flags: list[str], libs: tuple[str, ...] = ()) -> Path:
    result = run([tool("gcc"), *STRICT, *flags, *map(str, sources), "-o", str(out), *libs])
    assert result.returncode == 0, result.stderr
    assert result.stderr == "", result.stderr
    return out


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("imu_link")


@pytest.fixture(scope="module")
def example_exe(build: Path) -> Path:
    sources = [LIB / "examples" / "posix_device.c", LIB / "imu_link.c"]
    return compile_c(build / "posix_device", sources, ["-O2"], ("-lm",))


class ExampleDevice:
    """The example device running in its own process; ``port`` is its pty."""

    def __init__(self, exe: Path, *args: str) -> None:
        self.proc = subprocess.Popen([str(exe), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        assert line.startswith("PORT "), (line, self.proc.stderr.read() if self.proc.stderr else "")
        self.port = line.split(" ", 1)[1].strip()

    def stop(self) -> None:
        self.proc.terminate()
        assert self.proc.wait(timeout=5) == 0  # it ends cleanly on SIGTERM


@pytest.fixture
def example(example_exe: Path) -> Iterator[ExampleDevice]:
    device = ExampleDevice(example_exe, "--seed", "5")
    try:
        yield device
    finally:
        device.stop()


# ---- the library itself -------------------------------------------------------------------------


def undefined_symbols(nm: str, obj: Path) -> set[str]:
    result = run([nm, "-u", str(obj)])
    assert result.returncode == 0, result.stderr
    return {line.split()[-1] for line in result.stdout.splitlines() if line.strip()}


def test_library_compiles_warning_free_with_gcc_and_calls_nothing_but_string_h(build: Path) -> None:
    extra = ["-Wshadow", "-Wconversion", "-Wcast-qual", "-Wstrict-prototypes", "-Wmissing-prototypes", "-c"]
    small = ["-DIMU_LINK_RX_MAX_PAYLOAD=64", "-DIMU_LINK_RING_SIZE=64"]  # a board short of RAM
    for name, defines in (("default", []), ("small", small)):
        obj = compile_c(build / f"imu_link_{name}.o", [LIB / "imu_link.c"], [*extra, *defines])
        assert undefined_symbols("nm", obj) <= ALLOWED_CALLS
    includes = set(re.findall(r"#include [<\"]([^>\"]+)[>\"]", (LIB / "imu_link.c").read_text()
                              + (LIB / "imu_link.h").read_text()))
    assert includes == {"imu_link.h", "stdint.h", "stddef.h", "string.h"}


def test_library_builds_for_a_cortex_m4_and_reports_its_code_size(build: Path) -> None:
    obj = build / "imu_link_m4.o"
    gcc = tool("arm-none-eabi-gcc")
    result = run([gcc, *CORTEX_M4, *STRICT, "-c", str(LIB / "imu_link.c"), "-o", str(obj)])
    assert result.returncode == 0 and result.stderr == "", result.stderr
    size = run([tool("arm-none-eabi-size"), str(obj)])
    assert size.returncode == 0, size.stderr
    text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
    print(f"imu_link on Cortex-M4 (-Os): text {text} B, data {data} B, bss {bss} B")
    assert 0 < text <= CODE_BUDGET
    assert data == 0 and bss == 0  # no global state: every byte of RAM is in the user's objects
    assert undefined_symbols(tool("arm-none-eabi-nm"), obj) <= ALLOWED_CALLS


def test_c_unit_tests_pass_under_sanitizers(build: Path) -> None:
    sources = [LIB / "tests" / "test_imu_link.c", LIB / "imu_link.c"]
    exe = compile_c(build / "test_imu_link", sources, SANITIZE)
    result = run([str(exe)])
    print(result.stdout)
    match = re.search(r"^(\d+) passed, (\d+) failed$", result.stdout, re.M)
    assert match, result.stdout + result.stderr
    assert int(match[2]) == 0 and result.returncode == 0, result.stdout + result.stderr
    listed = re.findall(r'^\s*\{"\w+", test_\w+\},$', (LIB / "tests" / "test_imu_link.c").read_text(), re.M)
    assert int(match[1]) == len(listed) > 20  # every test in the runner's table ran


@pytest.mark.parametrize("rx_max", [None, 64])
def test_fuzzing_the_parser_finds_no_crash_overrun_or_disagreement(build: Path, rx_max: int | None) -> None:
    defines = [f"-DIMU_LINK_RX_MAX_PAYLOAD={rx_max}"] if rx_max else []
    exe = compile_c(build / f"fuzz_parser_{rx_max}", [LIB / "tests" / "fuzz_parser.c", LIB / "imu_link.c"],
                    SANITIZE + defines)
    result = run([str(exe), "20261124", str(FUZZ_STREAMS)])
    print(result.stdout)
    assert result.returncode == 0 and result.stderr == "", result.stdout + result.stderr
    match = re.search(r"fuzz: (\d+) streams \((\d+) random, (\d+) bit-flipped\), (\d+) bytes, "
                      r"(\d+) commands, (\d+) errors counted, (\d+) mismatches, (\d+) intact frames missed",
                      result.stdout)
    assert match, result.stdout
    streams, random_, flipped, n_bytes, commands, errors, mismatches, missed = map(int, match.groups())
    assert streams == FUZZ_STREAMS and random_ > 0 and flipped > 0
    assert n_bytes > 1_000_000 and commands > 1000 and errors > 1000
    assert mismatches == 0 and missed == 0


@pytest.mark.parametrize("rx_max", [None, 64])
def test_the_resyncs_worst_byte_is_the_one_the_header_states(build: Path, rx_max: int | None) -> None:
    """205 false starts 5 bytes apart, each ending at the buffer's last byte: that byte costs CRCs over
    105,985 bytes (measured by counting what the CRCs cover); the header states that number."""
    defines = [f"-DIMU_LINK_RX_MAX_PAYLOAD={rx_max}"] if rx_max else []
    exe = compile_c(build / f"resync_cost_{rx_max}", [LIB / "tests" / "resync_cost.c"], SANITIZE + defines)
    result = run([str(exe)])
    assert result.returncode == 0 and result.stderr == "", result.stdout + result.stderr
    match = re.fullmatch(r"worst_byte_crc_bytes (\d+) false_starts (\d+) clean_byte_crc_bytes (\d+)\n",
                         result.stdout)
    assert match, result.stdout
    worst, starts, clean = map(int, match.groups())
    capacity = (rx_max or 1024) + 7
    assert abs(worst - capacity**2 / 10) < 0.1 * capacity**2 / 10  # the header's rule of thumb
    assert clean == 5  # a clean stream's byte: one SET_RATE frame's CRC
    if rx_max is None:
        header = " ".join((LIB / "imu_link.h").read_text().split())
        assert f"{starts} overlapping false starts" in header and f"CRCs over {worst} bytes" in header
        assert (worst, starts) == (105_985, 205)


RING_8_BIT = r"""
#include <stdio.h>
#include "imu_link.h"

int main(void)
{
    imu_link_ring_t r;
    unsigned long put = 0, got = 0, errors = 0;
    uint8_t byte, expect = 0;
    int burst, k;
    imu_link_ring_init(&r);
    if (sizeof r.head != 1u || sizeof r.tail != 1u) {
        printf("indices of %u bytes\n", (unsigned)sizeof r.head);
        return 1;
    }
    for (burst = 0; burst < 400; burst++) {  /* wraps the 8-bit indices many times */
        for (k = 0; k < 1 + burst % 150; k++) {
            put += (unsigned long)imu_link_ring_put(&r, (uint8_t)put);
        }
        while (imu_link_ring_get(&r, &byte)) {
            errors += byte != expect;
            expect++;
            got++;
        }
    }
    printf("put %lu got %lu dropped %lu errors %lu\n", put, got, (unsigned long)r.dropped, errors);
    return 0;
}
"""


def test_the_ring_takes_8_bit_indices_for_8_bit_parts(build: Path) -> None:
    """-DIMU_LINK_RING_INDEX=uint8_t makes head and tail one byte each (read whole on an 8-bit part),
    the queue still full at IMU_LINK_RING_SIZE and in order across the indices' wrap; a size the 8-bit
    indices cannot tell full from empty (256) does not compile."""
    source = build / "ring_8_bit.c"
    source.write_text(RING_8_BIT, encoding="utf-8")
    flags = SANITIZE + [f"-I{LIB}", "-DIMU_LINK_RING_INDEX=uint8_t", "-DIMU_LINK_RING_SIZE=128"]
    exe = compile_c(build / "ring_8_bit", [source, LIB / "imu_link.c"], flags)
    result = run([str(exe)])
    assert result.returncode == 0, result.stdout + result.stderr
    put, got, dropped, errors = map(int, re.findall(r"\d+", result.stdout))
    assert put == got > 20_000 and errors == 0
    assert dropped == sum(max(0, 1 + b % 150 - 128) for b in range(400))  # a burst beyond 128 drops the rest
    refused = run([tool("gcc"), *STRICT, "-DIMU_LINK_RING_INDEX=uint8_t", "-DIMU_LINK_RING_SIZE=256", "-c",
                   str(LIB / "imu_link.c"), "-o", str(build / "ring_256.o")])
    assert refused.returncode != 0 and "imu_link_ring_size_is_a_power_of_two" in refused.stderr


# ---- the parser against the station's decoder ----------------------------------------------------


def damaged_command_stream(rng: np.random.Generator) -> bytes:
    """Commands of every length, garbage between some, some cut short, bits flipped; then zeros
    enough to settle any frame still waiting for the bytes its length claims."""
    parts = []
    for _ in range(400):
        if rng.random() < 0.15:
            junk = rng.integers(0, 256, size=int(rng.integers(1, 20)), dtype=np.uint8)
            junk[rng.random(len(junk)) < 0.3] = 0xA5
            parts.append(junk.tobytes())
        long_frame = rng.random() < 0.1
        length = int(rng.integers(0, native.MAX_PAYLOAD + 1 if long_frame else 6))
        frame = native.encode_frame(int(rng.integers(0x10, 0x20)), rng.bytes(length))
        if rng.random() < 0.1:
            frame = frame[: int(rng.integers(len(frame)))]
        parts.append(frame)
    data = bytearray(b"".join(parts))
    for at, bit in zip(rng.integers(0, len(data), 40), rng.integers(0, 8, 40), strict=True):
        data[at] ^= 1 << int(bit)
    return bytes(data) + bytes(native.MAX_PAYLOAD + 7)


def test_parser_finds_the_same_commands_as_the_station_decoder(build: Path) -> None:
    exe = compile_c(build / "parse_stream", [LIB / "tests" / "parse_stream.c", LIB / "imu_link.c"], SANITIZE)
    rng = np.random.default_rng(16)
    for _ in range(5):
        data = damaged_command_stream(rng)
        result = subprocess.run([str(exe)], input=data, capture_output=True, timeout=60)
        assert result.returncode == 0 and result.stderr == b"", result.stderr
        *lines, last = result.stdout.decode().splitlines()
        c_side = [(int(i), int(n), bytes.fromhex(h) if h else b"") for i, n, h in
                  (line.split(" ") for line in lines)]
        decoder = native.NativeDecoder()
        messages = []
        for start in range(0, len(data), 997):  # in chunks, as a port delivers them
            messages += decoder.feed(data[start:start + 997]).messages
        station_side = [(m.msg_id, len(m.payload), m.payload[:64]) for m in messages]
        # IMU_SAMPLE frames go to the station's sample path: only a CRC collision could make one here.
        assert [c for c in c_side if c[0] != native.IMU_SAMPLE] == station_side
        assert len(station_side) > 300 and int(last.split()[1]) > 0


# ---- the example device, served to the station ---------------------------------------------------


class Reader:
    """Reads a port and decodes it with the station's own decoder, keeping the raw bytes."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.decoder = native.NativeDecoder()
        self.raw = bytearray()
        self.messages: list[Message] = []
        self._batches: list[np.ndarray] = []

    def until(self, done: Callable[[list[Message]], bool], timeout: float) -> Reader:
        """Reads until ``done(messages)`` holds or ``timeout`` seconds have passed."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not done(self.messages):
            chunk = self.port.read(4096)
            self.raw += chunk
            out = self.decoder.feed(chunk)
            self.messages += out.messages
            self._batches.append(out.samples)
        return self

    @property
    def samples(self) -> np.ndarray:
        return join_batches(self._batches)


def never(messages: list[Message]) -> bool:
    return False


def acked(command_id: int) -> Callable[[list[Message]], bool]:
    return lambda messages: any(m.msg_id == native.ACK and m.payload[0] == command_id for m in messages)


def test_example_frames_are_the_station_encoding_bit_for_bit(example_exe: Path) -> None:
    device = ExampleDevice(example_exe, "--seed", "9")
    try:
        with serial.Serial(device.port, timeout=0.05) as port:
            reader = Reader(port)
            port.write(native.encode_frame(native.GET_INFO))
            reader.until(never, 0.6)  # samples stream meanwhile
            port.write(native.encode_frame(native.STOP_STREAM))
            reader.until(acked(native.STOP_STREAM), 3.0)
    finally:
        device.stop()
    stats, samples, raw = reader.decoder.stats, reader.samples, bytes(reader.raw)
    assert stats.crc_errors == stats.length_errors == stats.truncated == stats.garbage_bytes == 0
    assert [m.msg_id for m in reader.messages] == [native.DEVICE_INFO, native.ACK]
    # The whole stream is sample frames, one DEVICE_INFO and one ACK, byte for byte as the station
    # encodes them.
    info = native.encode_device_info(native.parse_device_info(reader.messages[0].payload))
    ack = native.encode_ack(native.STOP_STREAM)
    assert raw.count(info) == 1 and raw.endswith(ack)
    assert raw[: -len(ack)].replace(info, b"") == native.encode_samples(samples)
    assert len(samples) > 50
    assert np.all(np.diff(samples["seq"].astype(np.int64)) == 1)
    assert np.all(np.diff(samples["t_us"].astype(np.int64)) == 5000)  # 200 Hz on the device clock
    assert np.linalg.norm(samples["acc"].mean(axis=0)) == pytest.approx(G, rel=0.02)
    assert np.abs(samples["gyro"].mean(axis=0)).max() < 0.03
    assert 24.0 < float(samples["temp"].mean()) < 29.0


def test_example_device_info_is_escaped_json_the_station_reads(example_exe: Path) -> None:
    serial_number = 'SN "7" \\ tab\t bell\x07 e\u0301'
    device = ExampleDevice(example_exe, "--serial", serial_number, "--model", "m\n2", "--rate", "250")
    try:
        with serial.Serial(device.port, timeout=0.05) as port:
            port.write(native.encode_frame(native.GET_INFO))
            reader = Reader(port).until(lambda ms: any(m.msg_id == native.DEVICE_INFO for m in ms), 3.0)
    finally:
        device.stop()
    messages, raw = reader.messages, bytes(reader.raw)
    (info_message,) = [m for m in messages if m.msg_id == native.DEVICE_INFO]
    info = native.parse_device_info(info_message.payload)
    assert info == {"serial": serial_number, "model": "m\n2", "firmware": "imu_link 1.0", "rate_hz": 250}
    ascii_info = dict(info, serial=serial_number.replace("e\u0301", ""))  # json.dumps escapes non-ASCII
    assert info_message.payload.replace("e\u0301".encode(), b"") == json.dumps(
        ascii_info, separators=(",", ":")).encode()
    assert native.encode_frame(native.DEVICE_INFO, info_message.payload) in raw


def test_example_with_a_magnetometer_on_a_turntable(example_exe: Path) -> None:
    device = ExampleDevice(example_exe, "--mag", "--spin-dps", "90")
    try:
        with serial.Serial(device.port, timeout=0.05) as port:
            reader = Reader(port).until(lambda ms: False, 1.5)
    finally:
        device.stop()
    raw = bytes(reader.raw)
    samples = reader.samples
    assert has_mag(samples) and len(samples) > 100  # the station's native decoder reads IMU_MAG_SAMPLE frames
    assert not [m for m in reader.messages if m.msg_id == native.IMU_MAG_SAMPLE]
    for record in samples[:: max(1, len(samples) // 20)]:
        assert native.encode_frame(native.IMU_MAG_SAMPLE, record.tobytes()) in raw
    assert np.all(np.diff(samples["seq"].astype(np.int64)) == 1)
    assert np.degrees(samples["gyro"][:, 2].mean()) == pytest.approx(90, abs=1.0)
    assert np.linalg.norm(samples["mag"], axis=1).mean() == pytest.approx(np.hypot(22, 42), rel=0.02)
    # The field turns in the body frame at the table's rate: its heading advances 90 deg/s.
    heading = np.unwrap(np.arctan2(-samples["mag"][:, 1], samples["mag"][:, 0]))
    t = samples["t_us"] * 1e-6
    assert np.degrees(np.polyfit(t, heading, 1)[0]) == pytest.approx(90, rel=0.05)


def test_example_answers_every_host_command(example: ExampleDevice) -> None:
    with open_device(example.port) as dev:
        assert isinstance(dev, SerialDevice)
        assert dev.get_info()["rate_hz"] == 200
        dev.set_rate(100)
        assert dev.get_info()["rate_hz"] == 100
        dev.read(0.3)
        assert np.all(np.diff(dev.read(0.5)["t_us"].astype(np.int64)) == 10_000)
        for payload, status in ((b"\x01", native.ACK_BAD_ARGUMENT), (b"\x00\x00", native.ACK_BAD_ARGUMENT)):
            with pytest.raises(CommandRejected) as refused:
                dev.command(native.SET_RATE, payload)
            assert refused.value.status == status
        with pytest.raises(CommandRejected) as unknown:
            dev.command(0x1F)
        assert unknown.value.status == native.ACK_UNKNOWN
        dev.stop()
        dev.read(0.2)
        assert len(dev.read(0.4)) == 0
        dev.start()
        assert len(dev.read(0.4)) > 0
        dev.read(0.2)
        dev.command(native.RESTART)  # ACK ok, then the unit starts again as at power-up
        time.sleep(0.5)
        after = dev.read(0.1)
        resets = np.flatnonzero(np.diff(after["seq"].astype(np.int64)) < 0)
        restarted = after[resets[-1] + 1:] if len(resets) else after
        assert restarted["seq"][0] == 0 and restarted["t_us"][0] == 0
        assert np.all(np.diff(restarted["t_us"].astype(np.int64)) == 5000)  # back at its power-up rate
        assert dev.get_info()["rate_hz"] == 200
        assert dev.stats.errors == 0


def test_the_device_contract_suite_passes_on_the_example(example: ExampleDevice) -> None:
    result = run([sys.executable, "-m", "pytest", "tests/test_contract.py", "-k", "real", "--imu-port",
                  example.port, "-q", "-p", "no:xdist", "-p", "no:cacheprovider"], cwd=ROOT)
    summary = result.stdout.strip().splitlines()[-1]
    assert result.returncode == 0, result.stdout + result.stderr
    assert re.fullmatch(r"=* ?(\d+) passed, \d+ deselected in .*", summary), summary
    assert int(re.search(r"(\d+) passed", summary)[1]) >= 8  # type: ignore[index]


def test_capture_then_allan_noise_terms_on_the_example(example: ExampleDevice, tmp_path: Path) -> None:
    still = tmp_path / "still.h5"
    capture = run([*CLI, "capture", "--port", example.port, "--duration", "5", "-o", str(still)])
    assert capture.returncode == 0, capture.stderr
    samples = read_samples(still)
    assert len(samples) == pytest.approx(1000, abs=2)
    assert np.all(np.diff(samples["t_us"].astype(np.int64)) == 5000)
    allan = run([*CLI, "allan", str(still), "--terms", "N", "--json"])
    assert allan.returncode == 0, allan.stderr
    noise = json.loads(allan.stdout)["noise"]
    # The example's white noise, 0.002 rad/s and 0.02 m/s^2 per sample at 200 Hz, is what the
    # station's Allan engine finds: N = sigma / sqrt(rate), within what 5 s of record resolve
    # (runs of 3 s scatter by +-11 %).
    assert noise["gyro"]["N"] == pytest.approx([0.002 / np.sqrt(200)] * 3, rel=0.2)
    assert noise["accel"]["N"] == pytest.approx([0.02 / np.sqrt(200)] * 3, rel=0.2)


def test_tui_connects_to_the_example_and_shows_it_live(example: ExampleDevice) -> None:
    app = StationApp(TuiConfig(port=example.port))
    seen: dict[str, object] = {}

    async def drive() -> None:
        async with app.run_test(size=(120, 44)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the example device to connect")
            assert app.session is not None
            seen["info"] = dict(app.session.info)
            await pilot.press("enter")  # connect -> live view
            await wait_for(pilot, lambda: type(app.screen).__name__ == "LiveScreen", 5, "the live view")
            await wait_for(pilot, lambda: "rate 200.0 Hz" in screen_text(app), 15, "the live rate")
            seen["screen"] = screen_text(app)
            app.exit(0)

    asyncio.run(drive())
    assert seen["info"] == {"serial": "IMULINK-0001", "model": "imu_link POSIX example",
                            "firmware": "imu_link 1.0", "rate_hz": 200}
    screen = str(seen["screen"])
    assert "errors 0 (CRC 0)" in screen and "lost 0" in screen
    gravity = re.search(r"\|a\|\s+([0-9.]+)", screen)
    assert gravity and float(gravity[1]) == pytest.approx(G, rel=0.02)


def test_the_worked_example_in_the_manual_compiles(build: Path) -> None:
    page = (ROOT / "docs" / "workflows" / "own-board.md").read_text()
    section = page[page.index("## Give your board our protocol: the C library"):]
    code = re.search(r"```c\n(.*?)```", section, re.S)
    assert code, "the section has no C example"
    source = build / "board_main.c"
    source.write_text(code[1])
    flags = [*STRICT, "-Wmissing-prototypes", "-I", str(LIB), "-c", str(source)]
    result = run([tool("gcc"), *flags, "-o", str(build / "board_main.o")])
    assert result.returncode == 0 and result.stderr == "", result.stderr
    result = run([tool("arm-none-eabi-gcc"), *CORTEX_M4, *flags, "-o", str(build / "board_main_m4.o")])
    assert result.returncode == 0 and result.stderr == "", result.stderr


@pytest.mark.parametrize(("args", "message"), [
    (["--rate", "0"], "--rate 0: expected 1..8000 Hz"),
    (["--spin-dps", "fast"], "--spin-dps fast: not a number"),
    (["--serial"], "--serial needs a value"),
    (["--baud", "9600"], "unknown option --baud"),
])
def test_example_refuses_bad_options_with_exit_4(example_exe: Path, args: list[str], message: str) -> None:
    result = run([str(example_exe), *args])
    assert result.returncode == 4 and result.stdout == ""
    assert result.stderr.strip() == f"posix_device: {message}"
