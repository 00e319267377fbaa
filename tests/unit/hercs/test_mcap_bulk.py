"""hercs.run.runlog.mcap_bulk: the bytes of mcap's own Writer, message by message."""

import io

import mcap.writer
import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from hercs.run.runlog import mcap_bulk


def _file(bulk: bool, columns: list[list[bytes]], times: list[int]) -> bytes:
    out = io.BytesIO()
    writer = McapWriter(out, compression=CompressionType.ZSTD)
    writer.start()
    schema = writer.register_schema("s", "protobuf", b"schema")
    channels = [writer.register_channel(f"/t{i}", "protobuf", schema) for i in range(2)]
    writer.add_message(channels[0], 5, b"before", 5, 1)  # an index entry already there
    for sequence in (7, 8):  # two episodes: two chunks
        if bulk:
            mcap_bulk.add_message_rows(writer, channels, times, sequence, columns)
        else:
            for i, t in enumerate(times):
                for channel, column in zip(channels, columns, strict=True):
                    writer.add_message(channel, t, column[i], t, sequence)
        writer.flush()
    writer.finish()
    return out.getvalue()


def test_rows_make_the_file_add_message_makes() -> None:
    rng = np.random.default_rng(0)
    times = [1_764_000_000_000_000_000 + 40_000_000 * t for t in range(51)]
    columns = [[rng.bytes(int(rng.integers(0, 300))) for _ in times] for _ in range(2)]
    assert mcap_bulk.has_bulk_internals(McapWriter(io.BytesIO()))  # the bulk path is taken
    bulk = _file(True, columns, times)
    assert bulk == _file(False, columns, times)
    reader = make_reader(io.BytesIO(bulk))
    read = [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in reader.iter_messages()]
    assert len(read) == 1 + 2 * 2 * 51
    assert read[1:3] == [("/t0", times[0], 7, columns[0][0]), ("/t1", times[0], 7, columns[1][0])]
    assert reader.get_summary().statistics.message_count == len(read)


def test_an_mcap_without_the_internals_gets_the_same_file_message_by_message(
        monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(2)
    times = [1_764_000_000_000_000_000 + 40_000_000 * t for t in range(7)]
    columns = [[rng.bytes(int(rng.integers(0, 50))) for _ in times] for _ in range(2)]
    want = _file(False, columns, times)
    monkeypatch.setattr(mcap_bulk, "has_bulk_internals", lambda writer: False)
    assert _file(True, columns, times) == want


def test_reused_zstd_contexts_compress_to_the_same_bytes() -> None:
    mcap_bulk.reuse_zstd_contexts()
    mcap_bulk.reuse_zstd_contexts()  # idempotent
    data = np.random.default_rng(1).integers(0, 8, 50_000, dtype=np.uint8).tobytes()
    shim = mcap.writer.zstandard  # type: ignore[attr-defined]
    assert shim is not zstandard
    assert shim.compress(data) == shim.compress(data) == zstandard.compress(data)
    assert shim.ZstdDecompressor is zstandard.ZstdDecompressor
