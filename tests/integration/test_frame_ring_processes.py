"""The shared-memory frame ring across OS processes, without Zenoh: a reader process sees the
writer's pixels and leaves its segment alone; a writer process that ends unclosed leaves none."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from common.frame_ring import SEGMENT_PREFIX, RingWriter
from tests.unit.test_frame_ring import SLOTS, image, write


def test_another_process_reads_the_ring_and_leaves_it_in_place() -> None:
    """A reader process on /dev/shm itself: it sees the pixels, and its exit neither
    unlinks the writer's segment nor warns about it (no resource tracker involved)."""
    writer = RingWriter(SLOTS)
    try:
        ref = write(writer, image(7))
        code = textwrap.dedent(
            f"""
            import numpy as np
            from common.frame_ring import FrameRef, RingReader
            ref = FrameRef.from_map({ref.to_map()!r})
            view = RingReader().view(ref)
            print(int(np.frombuffer(view, np.uint8).astype(np.int64).sum()))
            """
        )
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        assert int(done.stdout) == int(image(7).astype(np.int64).sum())
        assert done.stderr == ""
        assert (Path("/dev/shm") / ref.segment).exists()
    finally:
        writer.close()
    assert not (Path("/dev/shm") / ref.segment).exists()


def test_a_writer_s_process_that_exits_without_closing_leaves_no_segment(tmp_path: Path) -> None:
    code = textwrap.dedent(
        f"""
        import numpy as np
        from pathlib import Path
        from common.frame_ring import RingWriter
        ring = RingWriter(4, Path({str(tmp_path)!r}))
        ring.write(np.zeros(64, np.uint8), (8, 8), "uint8")
        print(ring.segment)
        """
    )  # no close(): the process just ends
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith(SEGMENT_PREFIX)
    assert list(tmp_path.iterdir()) == []
