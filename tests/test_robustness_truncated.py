"""Crashed recordings: a teach file cut off anywhere is fitted from its complete prefix.

A recorder that crashes leaves no summary and no footer, and usually half a chunk. The
default teach is cut at 10 seeded random offsets between 20 % and 100 % of its size (4 of
them in the default suite, all 10 with ``-m campaign``), and
``hbvs fit`` must fit every prefix (exit 0), say how many frames it recovered, and use
exactly the image messages of the chunks that are complete. Those are counted here by an
independent pass: a small MCAP walker written for this test from the specification, which
shares no code with hbvs's reader or with the ``mcap`` library's.
"""

from __future__ import annotations

import random
import re
import struct
import zlib

from conftest import SUITE_OR_CAMPAIGN, call_hbvs, campaign_extent

SEED = 20031027
CUTS = 10
IMAGE_TOPIC = "/camera/image"


def complete_image_messages(data: bytes, topic: str = IMAGE_TOPIC) -> int:
    """Messages on ``topic`` in the complete records of ``data`` (chunks whose bytes and
    CRC are whole); stops at the first record that is cut."""
    import zstandard

    assert data[:8] == b"\x89MCAP0\r\n"
    channels: dict[int, str] = {}
    count = 0

    def records(buffer: bytes, offset: int):
        while offset + 9 <= len(buffer):
            opcode, length = struct.unpack_from("<BQ", buffer, offset)
            if offset + 9 + length > len(buffer):
                return
            yield opcode, buffer[offset + 9:offset + 9 + length]
            offset += 9 + length

    def take(opcode: int, body: bytes) -> None:
        nonlocal count
        if opcode == 0x04:  # channel: id, schema id, topic
            (size,) = struct.unpack_from("<I", body, 4)
            channels[struct.unpack_from("<H", body, 0)[0]] = body[8:8 + size].decode()
        elif opcode == 0x05 and channels.get(struct.unpack_from("<H", body, 0)[0]) == topic:
            count += 1

    for opcode, body in records(data, 8):
        if opcode == 0x06:  # chunk: times, uncompressed size and CRC, compression, records
            _start, _end, size, crc, name_size = struct.unpack_from("<QQQII", body, 0)
            compression = body[32:32 + name_size].decode()
            (stored,) = struct.unpack_from("<Q", body, 32 + name_size)
            packed = body[40 + name_size:40 + name_size + stored]
            plain = zstandard.ZstdDecompressor().decompress(packed, max_output_size=size) if compression else packed
            assert len(plain) == size and (crc == 0 or zlib.crc32(plain) == crc)
            for inner in records(plain, 0):
                take(*inner)
        else:
            take(opcode, body)
    return count


def fit_prefix(teach: bytes, cut: int, folder) -> tuple[int, int, str, object]:
    """Fit ``teach[:cut]`` with the CLI (in this process: the file, not the process, is what
    is cut); (cut, exit code, stderr, fit model or None)."""
    from hbvs_cli.io.fit_file import read_fit_file

    source, output = folder / f"cut{cut}.mcap", folder / f"fit{cut}.mcap"
    source.write_bytes(teach[:cut])
    result = call_hbvs("fit", str(source), "-q", "-o", str(output))
    model = read_fit_file(output).model if result.returncode == 0 else None
    return cut, result.returncode, result.stderr.decode(), model


@SUITE_OR_CAMPAIGN
def test_a_teach_cut_anywhere_fits_from_its_complete_prefix(default_teach, tmp_path, request, extent):
    teach = default_teach.read_bytes()
    rng = random.Random(SEED)
    cuts = sorted(rng.randrange(len(teach) // 5, len(teach)) for _ in range(CUTS))
    if not campaign_extent(request, extent):
        # The default suite fits 4 of the 10 prefixes, spread over the file (the shortest,
        # two in between, the longest); ``pytest -m campaign`` fits all 10.
        cuts = [cuts[0], cuts[3], cuts[6], cuts[-1]]
    assert complete_image_messages(teach) == 600  # the walker reads a whole file right
    results = [fit_prefix(teach, cut, tmp_path) for cut in cuts]
    for cut, code, stderr, model in results:
        expected = complete_image_messages(teach[:cut])
        assert code == 0, (cut, stderr)
        recovered = re.search(r"recovered (\d+) complete frames", stderr)
        assert recovered and int(recovered.group(1)) == expected, (cut, expected, stderr)
        assert model.frames.total == expected and model.frames.truncated_input is True, (cut, model.frames)
    # The cuts spread over the file: from a fifth of the frames to nearly all of them.
    totals = [model.frames.total for *_, model in results]
    assert min(totals) < 250 and max(totals) > 500, totals
