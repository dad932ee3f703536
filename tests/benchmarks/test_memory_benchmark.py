"""The memory benchmark prints the process's peak resident set size, as its last line."""

from dgsdp.benchmarks.memory import main, peak_rss_bytes


def test_prints_the_peak_rss_of_the_process(capsys):
    figures = main(["--size", "small", "--seconds", "12", "--steps", "2"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    fields = dict(part.split("=") for part in last.split())
    assert set(fields) == {"peak_rss_gib", "peak_rss_gb"}
    # against the kernel's own account of the peak (VmHWM in /proc, kB)
    hwm = next(line for line in open("/proc/self/status") if line.startswith("VmHWM:"))
    assert abs(int(hwm.split()[1]) * 1024 - peak_rss_bytes()) <= 0.05 * peak_rss_bytes()
    assert float(fields["peak_rss_gb"]) == round(figures["peak_bytes"] / 1e9, 2)
    assert float(fields["peak_rss_gib"]) == round(figures["peak_bytes"] / 2**30, 2)
    assert 0 < figures["before_bytes"] <= figures["peak_bytes"] <= peak_rss_bytes()


def test_student(capsys):
    main(["--size", "small", "--seconds", "6", "--steps", "2", "--student"])
    assert "small student" in capsys.readouterr().out
