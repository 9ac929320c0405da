"""Progress bars: drawn only on a terminal and never under --quiet."""
import io

from spikesim.progress import progress_bar, shows_progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_no_bars_when_not_a_terminal_or_quiet() -> None:
    assert not shows_progress(False, io.StringIO())
    assert not shows_progress(True, _Tty())
    assert shows_progress(False, _Tty())


def test_bar_is_silent_under_pytest_capture(capsys) -> None:
    # pytest's captured stderr is not a terminal: the bar must write nothing at all
    for _ in progress_bar(range(5), desc="job", unit="step"):
        pass
    assert capsys.readouterr().err == ""


def test_bar_shows_rate_and_eta_on_a_terminal(monkeypatch) -> None:
    tty = _Tty()
    monkeypatch.setattr("sys.stderr", tty)
    bar = progress_bar(total=4, desc="job", unit="step")
    for _ in range(4):
        bar.update(1)
    bar.close()
    text = tty.getvalue()
    assert "job" in text and "4/4" in text and "step/s" in text and "<" in text  # rate and ETA
