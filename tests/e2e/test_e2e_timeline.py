"""End to end: a recorded task scrubbed on the dashboard's Timeline in headless Chromium.

A robot is taught the corridor reference frames and sent somewhere with ``record: true``; the
query frames it streams are recorded, then the task is stopped. The browser opens the
Timeline tab, picks the recording, opens it and clicks the frame slider at a chosen frame; the
screenshot of the Timeline's camera tile is compared with that frame's recorded JPEG (and not
another frame's), and the belief shown is that frame's. The screenshot goes to the test's
temporary folder, or to ``TIMELINE_SCREENSHOT`` (``make screenshot`` refreshes
docs/img/timeline.png).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import cv2
import numpy as np
from playwright.sync_api import Error as PlaywrightError
from test_e2e_dashboard import chromium

from robot_client.client import TeachRepeatClient
from server.bench.common import corridor_marks
from server.recording.reader import read_recording
from web.bench import (
    FrameStreamer,
    headless_browser,
    query_frames,
    register,
    start_live_server,
    teach_corridor,
)
from web.imagery import PANEL_IMAGE_HEIGHT, decode_rgb

FRAMES = 24
CHOSEN = 17  # the frame clicked on the slider (0-based)
OTHER = 2


def difference(shown: np.ndarray, jpeg: bytes) -> float:
    """Mean absolute difference (grey levels) between a shown tile and a JPEG scaled to it."""
    expected = decode_rgb(jpeg)
    assert expected is not None
    h, w = shown.shape[:2]
    scaled = cv2.resize(expected, (w, h), interpolation=cv2.INTER_AREA)
    return float(np.abs(shown.astype(np.float64) - scaled.astype(np.float64)).mean())


def test_the_timeline_shows_a_chosen_frames_camera_image_and_belief(
    tmp_path: Path, shared_data: Path
) -> None:
    executable = chromium()
    screenshot = Path(os.environ.get("TIMELINE_SCREENSHOT") or tmp_path / "timeline.png")
    live = start_live_server(tmp_path / "timeline.sqlite")
    dashboard = live.dashboard
    assert dashboard is not None
    try:
        token = register(live.url, "rover")
        with TeachRepeatClient(live.url, token) as client:
            teach_corridor(client, shared_data)
            client.goto("rover", corridor_marks()[max(corridor_marks())], record=True)
            streamer = FrameStreamer(client, "rover", query_frames(shared_data), goals=())
            streamer.send(FRAMES)
            client.stop("rover")
            assert streamer.sent == FRAMES and not streamer.errors, streamer.errors
        live.services.recordings.wait_idle()
        (found,) = live.services.recordings.store.files()
        recording = read_recording(found.path)
        assert recording.complete and len(recording.frames) == FRAMES
        dashboard.refresh()  # lists the recording in the Timeline's dropdown

        with headless_browser(dashboard.url, executable=executable) as page:
            page.wait_for_selector("canvas", timeout=30_000)
            page.get_by_role("tab", name="Timeline").click()
            page.get_by_role("combobox", name="Recording").click()
            page.get_by_role("option", name=found.name).click()
            page.get_by_role("button", name="Open", exact=True).click()
            page.get_by_text(f"{FRAMES} frames over").first.wait_for(timeout=30_000)
            # click the slider's track where the chosen frame is, as a user would
            track = page.locator(".mantine-Slider-root").first
            box = track.bounding_box()
            assert box is not None
            track.click(
                position={"x": box["width"] * CHOSEN / (FRAMES - 1), "y": box["height"] / 2}
            )
            controls = dashboard.timeline.controls
            assert controls is not None
            for _ in range(50):  # the click's message reaches the server
                if int(controls.frame.value) != 0:
                    break
                page.wait_for_timeout(100)
            chosen = int(controls.frame.value)
            assert abs(chosen - CHOSEN) <= 1, chosen
            frame = recording.frames[chosen]
            # the belief of that frame is shown: its top state and the entropy
            belief = frame.belief
            assert belief is not None
            top = belief["top"][0]
            expected_line = f"{top['probability']:.2f} {top['name']}"
            page.get_by_text(f"entropy {belief['entropy']:.2f} nats").first.wait_for(timeout=10_000)
            body = " ".join(page.locator("body").inner_text().split())
            assert expected_line in body, body[-1500:]
            page.wait_for_timeout(1500)  # the image has arrived
            notices = page.locator(".mantine-Notification-closeButton")  # viser's WebGL notice
            for _ in range(5):
                if notices.count() == 0:
                    break
                with contextlib.suppress(PlaywrightError):  # may close by itself first
                    notices.first.click(timeout=1000)
                page.wait_for_timeout(300)
            screenshot.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(screenshot))
            # the Timeline's first image: camera | matched taught image, captions on top
            boxes = [img.bounding_box() for img in page.locator("img").all()]
            in_panel = [
                b for b in boxes if b and b["x"] > 800 and b["width"] > 300 and b["height"] > 100
            ]
            assert in_panel, boxes
            tile_box = min(in_panel, key=lambda b: b["y"])
        shot = cv2.imread(str(screenshot))[:, :, ::-1]
        x0, y0 = round(tile_box["x"]), round(tile_box["y"])
        w, h = round(tile_box["width"]), round(tile_box["height"])
        tile = shot[y0 : y0 + h, x0 : x0 + w]
        # the camera's part of the drawn tile: below the caption bar, left of the matched image
        drawn = dashboard.timeline._images(frame, chosen, FRAMES)
        cam = decode_rgb(frame.jpeg)
        assert cam is not None
        left = round(cam.shape[1] * PANEL_IMAGE_HEIGHT / cam.shape[0]) / drawn.shape[1]
        top_bar = 26 / drawn.shape[0]
        camera = tile[round(h * top_bar) + 2 : h - 2, 2 : round(w * left) - 2]
        mine = difference(camera, frame.jpeg)
        other = difference(camera, recording.frames[OTHER].jpeg)
        assert mine < 20 and other > mine + 5, (mine, other)
    finally:
        live.stop()
    assert screenshot.stat().st_size > 50_000
