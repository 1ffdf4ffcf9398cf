"""Which checksum fits frames a description's checksum refuses: the diagnosis of a wrong ``checksum`` key.

A frame description that names the wrong checksum type (``crc8`` for a board that sends ``xor8``)
refuses nearly every frame: the decoder counts CRC errors and keeps the few whose bytes match by
chance. Given the bytes of refused frames (sync and length right), :func:`fitting_checksums` tries
every checksum type of ``specs/frame-description.md`` over the covered ranges a board plausibly uses
(the description's own, from the frame's start or from after the sync, up to the checksum field,
which sits where the description says or at the frame's end) and both byte orders, and returns those
that fit nearly all of them; :func:`describe_checksum` writes one as the description's YAML.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from protocols.frame_checksums import CHECKSUM_SIZES, CHECKSUM_TYPES, checksum_rows
from protocols.frame_description import ChecksumSpec, FrameDescription

MIN_FRAMES = 8
"""Fewer refused frames than this show nothing (a chance match of an 8-bit sum is 1 in 256)."""
FIT_SHARE = 0.9
"""A checksum fits when it matches this share of the refused frames (the rest: real damage)."""


@dataclass(frozen=True)
class ChecksumFit:
    """A checksum that fits refused frames: how, and how many of them."""

    spec: ChecksumSpec
    matched: int
    frames: int


def _stored(frames: np.ndarray, spec: ChecksumSpec) -> np.ndarray:
    """The checksum field's value in every frame, in the spec's byte order."""
    field = frames[:, spec.at : spec.at + spec.size].astype(np.uint64)
    if spec.byte_order == "little":
        field = field[:, ::-1]
    value = np.zeros(len(frames), dtype=np.uint64)
    for col in range(spec.size):
        value = (value << np.uint64(8)) | field[:, col]
    return value


def matches(frames: np.ndarray, spec: ChecksumSpec) -> int:
    """How many of ``frames`` (``(n, length)`` of ``uint8``) carry the checksum ``spec`` describes."""
    computed = checksum_rows(spec.type, frames[:, spec.start : spec.end]).astype(np.uint64)
    return int(np.count_nonzero(computed == _stored(frames, spec)))


def _candidates(desc: FrameDescription) -> list[ChecksumSpec]:
    """Every checksum a board of this frame plausibly uses, the described layout first."""
    described = desc.checksum
    assert described is not None
    length = desc.length
    out: list[ChecksumSpec] = []
    for name in CHECKSUM_TYPES:
        size = CHECKSUM_SIZES[name]
        if size == 0:
            continue
        ats = dict.fromkeys([described.at] if size == described.size else [])
        ats[length - size] = None
        for at in ats:
            for start in dict.fromkeys((described.start, len(desc.sync), 0)):
                for end in dict.fromkeys((described.end, at)):
                    if not start < end <= at:
                        continue  # the covered bytes end before the field: a layout of the spec's kind
                    for order in dict.fromkeys((described.byte_order, "little", "big") if size > 1
                                               else (described.byte_order,)):
                        out.append(ChecksumSpec(name, start, end, at, order))
    return out


def fitting_checksums(desc: FrameDescription, frames: np.ndarray) -> list[ChecksumFit]:
    """The checksums other than the described one that fit nearly all ``frames``, best first.

    Parameters
    ----------
    desc : FrameDescription
        The description whose checksum refused the frames (it has one).
    frames : numpy.ndarray
        ``(n, desc.length)`` of ``uint8``: refused frames, each starting with the sync.

    Returns
    -------
    list of ChecksumFit
        Those matching at least ``FIT_SHARE`` of the frames (none with fewer than ``MIN_FRAMES``
        frames), the most matches first, then the layout closest to the described one.
    """
    if desc.checksum is None or len(frames) < MIN_FRAMES:
        return []
    fits = []
    for spec in _candidates(desc):
        if spec == desc.checksum:
            continue
        found = matches(frames, spec)
        if found >= FIT_SHARE * len(frames):
            fits.append(ChecksumFit(spec, found, len(frames)))
    # stable: among equal counts the candidates' order (the described layout first) decides
    return sorted(fits, key=lambda fit: -fit.matched)


def describe_checksum(spec: ChecksumSpec, desc: FrameDescription) -> str:
    """``{type: xor8, from: 2, to: -1, at: -1}``: the checksum as the description's YAML writes it."""
    length = desc.length
    to = spec.end - length if spec.end < length else spec.end  # negative counts from the frame's end
    parts = [f"type: {spec.type}", f"from: {spec.start}", f"to: {to}", f"at: {spec.at - length}"]
    if spec.size > 1 and spec.byte_order != desc.byte_order:
        parts.append(f"byte_order: {spec.byte_order}")
    return "{" + ", ".join(parts) + "}"


def diagnosis(desc: FrameDescription, frames: np.ndarray, failed: int, total: int) -> str:
    """One line: how many frames failed the described checksum, and the checksum that fits them.

    Parameters
    ----------
    desc : FrameDescription
        The description (it has a checksum).
    frames : numpy.ndarray
        Refused frames, as for :func:`fitting_checksums`.
    failed, total : int
        Frames that failed their checksum, and frames seen (good and failed).

    Returns
    -------
    str
        What failed, what fits (or what else to check), what to change.
    """
    assert desc.checksum is not None
    said = describe_checksum(desc.checksum, desc)
    head = f"{failed} of {total} frames failed the description's checksum {said}"
    fits = fitting_checksums(desc, frames)
    if fits:
        best = fits[0]
        return (f"{head}; {describe_checksum(best.spec, desc)} fits {best.matched} of the {best.frames} "
                f"frames refused last: write that as the description's checksum")
    return (f"{head}, and no other checksum type fits the frames refused last: check the checksum's from, "
            f"to and at, the length and the sync (imu-station frame guess proposes them from a raw capture)")


def with_checksum(desc: FrameDescription, spec: ChecksumSpec) -> FrameDescription:
    """``desc`` with its checksum replaced (to decode with the one that fits)."""
    return replace(desc, checksum=spec)
