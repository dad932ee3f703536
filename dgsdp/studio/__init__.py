"""The dance studio: a local web page (Gradio) to generate, watch, edit and download dances.

Start it with ``dgsdp-studio`` or ``python -m dgsdp.studio`` (see ``--help``). The page code is in
:mod:`dgsdp.studio.app`, the viewer in :mod:`dgsdp.studio.viewer`, and the link to the generation pipeline in
:mod:`dgsdp.studio.engine`.
"""

from __future__ import annotations


def main(argv: list[str] | None = None) -> None:
    """Start the studio (``dgsdp-studio``); one clear message when Gradio is not installed."""
    try:
        import gradio  # noqa: F401
    except ImportError:
        raise SystemExit(
            "error: the studio needs Gradio: pip install -e '.[studio]' (or pip install 'gradio>=6.10')"
        ) from None
    from dgsdp.studio.app import main as run

    run(argv)
