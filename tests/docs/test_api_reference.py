"""The API reference page (docs/reference/api.md, rendered by mkdocstrings) covers every public name of the
package, and every public name, method and property there has a docstring to render."""

import inspect
import re
from pathlib import Path

import dgsdp
from dgsdp import registry

PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "api.md"


def documented() -> set[str]:
    """The objects the page renders (``::: module.Name``)."""
    return set(re.findall(r"^::: ([\w.]+)$", PAGE.read_text(), flags=re.M))


def test_every_public_name_is_on_the_page():
    names = [n for n in dgsdp.__all__ if n != "__version__"]
    paths = {f"{getattr(dgsdp, n).__module__}.{n}" for n in names}
    assert paths <= documented(), paths - documented()
    assert "dgsdp.registry" in documented()


def test_every_public_name_has_docstrings_to_render():
    missing = []
    for name in (n for n in dgsdp.__all__ if n != "__version__"):
        obj = getattr(dgsdp, name)
        if not inspect.getdoc(obj):
            missing.append(name)
        if inspect.isclass(obj):
            for attr, value in vars(obj).items():
                if attr.startswith("_"):
                    continue
                member = value.fget if isinstance(value, property) else getattr(value, "__func__", value)
                if callable(member) and not inspect.getdoc(member):
                    missing.append(f"{name}.{attr}")
    for name in ("register", "build", "resolve", "check_plain", "check_no_targets"):
        if not inspect.getdoc(getattr(registry, name)):
            missing.append(f"registry.{name}")
    assert not missing, missing
