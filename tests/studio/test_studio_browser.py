"""The studio in a real browser (system chromium via pytest-playwright): generate, play, download, errors.

The page is loaded with every request to a host other than 127.0.0.1 aborted and recorded: it must work
without the internet and ask for nothing outside this machine.
"""

import re
import urllib.parse
import urllib.request
from html.parser import HTMLParser

import numpy as np
import pytest

pytest.importorskip("gradio", reason="the studio needs Gradio: pip install -e '.[studio]'")
bvh = pytest.importorskip("bvh")

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]

GENERATE_TIMEOUT_MS = 120_000


def _is_local(url: str) -> bool:
    parsed = urllib.parse.urlparse(url)
    return parsed.scheme in ("data", "blob", "about") or parsed.hostname in ("127.0.0.1", "localhost")


def open_studio(page, url: str) -> list[str]:
    """Load the page with the internet cut off; returns the list that collects any outside request."""
    outside: list[str] = []

    def route(r):
        if _is_local(r.request.url):
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    page.goto(url)
    page.wait_for_selector("#generate")
    page.wait_for_function("document.querySelector('.dgsdp-viewer') !== null")
    return outside


def upload_and_generate(page, song) -> None:
    clear = page.locator("#song button[aria-label='Clear']")
    if clear.count():
        clear.click()
    page.set_input_files("#song input[type=file]", str(song))
    page.wait_for_selector(f"#song td.filename[aria-label='{song.name}']")
    page.click("#generate")


def wait_for_dance(page, frames: int) -> None:
    page.wait_for_function(
        f"document.querySelector('.dgsdp-viewer').dataset.frames === '{frames}'", timeout=GENERATE_TIMEOUT_MS
    )


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "script" and a.get("src"):
            self.refs.append(a["src"])
        if tag == "link" and a.get("href"):
            self.refs.append(a["href"])


def test_page_and_its_assets_reference_no_outside_host(studio_url):
    with urllib.request.urlopen(studio_url) as r:
        html = r.read().decode()
    tags = _Tags()
    tags.feed(html)
    assert tags.refs, "the page should load its scripts and styles"
    for ref in tags.refs:
        full = urllib.parse.urljoin(studio_url, ref)
        assert _is_local(full), f"the page loads {ref} from outside this machine"
        if full.endswith(".css"):
            with urllib.request.urlopen(full) as r:
                css = r.read().decode()
            imports = re.findall(r"@import\s+(?:url\()?['\"]?([^'\")\s;]+)", css)
            urls = [u for u in re.findall(r"url\(\s*['\"]?([^'\")]+)", css) if not u.startswith("data:")]
            outside = [u for u in imports + urls if not _is_local(urllib.parse.urljoin(full, u))]
            assert not outside, f"{ref} loads {outside}"


def test_generate_play_and_download(page, studio_url, studio_songs):
    outside = open_studio(page, studio_url)
    upload_and_generate(page, studio_songs["three"])
    wait_for_dance(page, 90)  # 3 s at 30 FPS

    # the viewer plays in sync with the song: the audio clock runs and the frame shown follows it
    page.click(".dv-play")
    page.wait_for_function("document.querySelector('.dv-audio').currentTime > 0.4", timeout=20_000)
    first = int(page.eval_on_selector(".dgsdp-viewer", "e => e.dataset.frame"))
    page.wait_for_function(f"Number(document.querySelector('.dgsdp-viewer').dataset.frame) > {first}", timeout=20_000)
    frame, seconds = page.evaluate(
        "[Number(document.querySelector('.dgsdp-viewer').dataset.frame), document.querySelector('.dv-audio').currentTime]"
    )
    assert abs(frame - seconds * 30) <= 6, (frame, seconds)  # a few frames of rendering lag at most
    assert re.search(r"frame \d+ / 90", page.inner_text(".dv-counter"))

    # the downloads: pkl, bvh, npy and the video; the BVH parses and has one frame per motion frame
    names = page.inner_text("#downloads")
    for suffix in (".pkl", ".bvh", ".npy", ".mp4"):
        assert suffix in names, names
    with page.expect_download() as info:
        page.click("#downloads a[href$='.bvh']")
    path = info.value.path()
    mocap = bvh.Bvh(open(path).read())
    assert mocap.nframes == 90
    assert abs(mocap.frame_time - 1 / 30) < 1e-6
    assert len(mocap.get_joints_names()) == 24
    with page.expect_download() as info:
        page.click("#downloads a[href$='.npy']")
    before = np.load(info.value.path())
    assert before.shape == (90, 151)

    # an edit from the page: regenerate 1-2 s, keep the rest of the current dance
    status = page.inner_text("#status")
    page.click("text=Edit the current dance")
    page.click("#edit-kind label:has-text('Regenerate a time range')")
    page.fill("#range-start input", "1")
    page.fill("#range-end input", "2")
    page.click("#apply-edit")
    page.wait_for_function(f"document.querySelector('#status').innerText !== {status!r}", timeout=GENERATE_TIMEOUT_MS)
    with page.expect_download() as info:
        page.click("#downloads a[href$='.npy']")
    after = np.load(info.value.path())
    np.testing.assert_allclose(after[:30], before[:30], atol=1e-4)
    np.testing.assert_allclose(after[60:], before[60:], atol=1e-4)
    assert np.abs(after[30:60] - before[30:60]).max() > 1e-2
    assert outside == [], f"the page asked for outside resources: {outside}"


def test_errors_appear_in_the_page(page, studio_url, studio_songs):
    open_studio(page, studio_url)
    upload_and_generate(page, studio_songs["broken"])
    page.get_by_text("Cannot decode audio file").first.wait_for(timeout=GENERATE_TIMEOUT_MS)
    upload_and_generate(page, studio_songs["long"])
    page.get_by_text("this studio takes songs up to 20 s (its --max-seconds setting)").first.wait_for(
        timeout=GENERATE_TIMEOUT_MS
    )
    assert page.eval_on_selector(".dgsdp-viewer", "e => e.dataset.frames") == "0"  # no dance was shown

    checkpoint = page.locator("#checkpoint input")
    checkpoint.fill("/nowhere/model.ckpt")
    checkpoint.press("Enter")
    page.get_by_text("choose one of the models listed in the Model box").first.wait_for(timeout=30_000)


def test_two_sessions_get_their_own_dances(browser, studio_url, studio_songs):
    pages = [browser.new_context().new_page() for _ in range(2)]
    for page in pages:
        open_studio(page, studio_url)
    upload_and_generate(pages[0], studio_songs["three"])
    upload_and_generate(pages[1], studio_songs["two"])  # queued behind the first
    wait_for_dance(pages[0], 90)
    wait_for_dance(pages[1], 60)
    links = [page.eval_on_selector("#downloads a[href$='.npy']", "e => e.href") for page in pages]
    assert "three.npy" in links[0] and "two.npy" in links[1]
    folders = [re.search(r"files in (\S+)", page.inner_text("#status")).group(1) for page in pages]
    assert folders[0] != folders[1]  # each request writes into its own folder
    for page in pages:
        page.context.close()
