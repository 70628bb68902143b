"""Progress reports (dejax.progress): the line, honest failures, terminal redraws, chunking
and the projected wall time."""
from dejax import progress as pg


def test_progress_line_and_honest_failure():
    import io

    s = pg.format_line(50, 100, 0.5, 1.0, 2.0)
    assert "50%" in s and "step 50/100" in s and "t = 0.5/1 s" in s and "25 steps/s" in s and "ETA 0:00:02" in s
    buf = io.StringIO()
    bar = pg.ProgressBar(100, 1.0, stream=buf, interval=0.0)
    bar.compiling("x")
    assert buf.getvalue() == "compiling x ...\n"
    bar.compiling("x", cached=True)
    assert "loaded from the compile cache" in buf.getvalue().splitlines()[-1]
    bar(100, 100, 1.0, 1.0)  # the chunk end a failure hides
    bar.close(failed=True, k=42, t=0.42)
    last = buf.getvalue().rstrip("\n").splitlines()[-1]
    assert last.startswith("failed after step 42/100 (42%") and "100%" not in last
    quiet = io.StringIO()
    q = pg.ProgressBar(10, 1.0, quiet=True, stream=quiet)
    q.compiling()
    q(10, 10, 1.0, 1.0)
    q.close()
    assert quiet.getvalue() == ""


def test_chunks_are_small_and_projection_scales():
    assert pg.chunk_steps(3000, 4e-4) == 30  # 1 % of the run
    assert pg.chunk_steps(3334, 1.92) == 1  # paper tube: one step per update
    assert pg.chunk_steps(5, 1e-4) == 1
    assert pg.chunk_steps(3000, 4e-4, frames=500) == 6  # VTU frames are taken at chunk ends
    assert pg.projected_seconds(960, 3334) > 3600 > pg.projected_seconds(1, 3000)


def test_progress_redraws_in_place_on_a_terminal():
    import io

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    bar = pg.ProgressBar(4, 0.4, stream=term, interval=0.0)
    for k in range(1, 5):
        bar(k, 4, 0.1 * k, 0.1 * k)
    bar.close()
    text = term.getvalue()
    assert text.count("\r") == 5 and text.count("\n") == 1 and text.endswith("\n")
    assert "step 4/4" in text.split("\r")[-1] and "100%" in text.split("\r")[-1]
    slow = Terminal()
    bar = pg.ProgressBar(1000, 1.0, stream=slow, interval=60.0)  # throttled: only the first update drawn
    for k in range(1, 1001):
        bar(k, 1000, k / 1000, 1.0)
    assert slow.getvalue().count("\r") == 1
