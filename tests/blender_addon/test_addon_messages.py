"""Relight Photo add-on: what the artist is told is what happened, and what to do (issue 40).

- A photo whose header claims 20000 x 20000 pixels was decoded by Pillow on the worker and
  reported as "The network failed (DecompressionBombError: ...)": the network never ran. It is
  refused from its header, before Blender or the worker decodes it, saying it is too large and
  what allows it (the panel's Max Photo Size, within relight.files.image_limits).
- Reopened after the photo was moved, deleted or replaced, Photo Light -> World said the photo
  was "still being read after opening the file: try again in a moment": nothing was being read.
- A full disk while the .blend was saved named one photo whose saved relight was not written
  though several were not, and (numpy 1.x, bpy 5.0) printed "Exception ignored in
  ZipFile.__del__ ... [Errno 28]" once per file.
Pressed as a click does (the operators, the panel's settings), the message asserted whole.
"""

from __future__ import annotations

import errno
import io
import os

import pytest

import bpy

from blender_addon.blender import bl_images
from blender_addon.worker import state
from fuzz_support import jpeg_bytes


def _relight(name):
    return bpy.ops.relight_photo.relight(image_name=name, synchronous=True)


def _status():
    return bpy.context.window_manager.relight_photo_status


# ------------------------------------------------------------------ too large

def test_a_photo_claiming_20000_squared_is_refused_as_too_large_before_anything_decodes_it(addon):
    forged = addon / "huge.jpg"
    forged.write_bytes(jpeg_bytes(declared=(20000, 20000)))
    photo = bpy.data.images.load(str(forged))
    with pytest.raises(RuntimeError) as refused:
        _relight(photo.name)
    said = _status().message
    assert said == ("'huge.jpg' is 400 MP: too large to relight (at most 150 MP and "
                    "40,000 pixels a side). Scale it down in an image editor and open the smaller copy.")
    assert said in str(refused.value) and "network" not in said.lower() and _status().is_error
    assert not bpy.data.images["huge.jpg"].has_data  # Blender was not made to decode 1.6 GB either
    assert not any(i.name.startswith("huge.jpg.") for i in bpy.data.images)  # no outputs


def test_a_photo_over_max_photo_size_says_how_to_allow_it(addon):
    from PIL import Image

    import numpy as np

    # a real (whole) 3000 x 2000 PNG: 6 MP, over a Max Photo Size of 5 MP
    rng = np.random.default_rng(1)
    Image.fromarray(rng.integers(0, 256, (2000, 3000, 3), dtype=np.uint8)).save(addon / "big.png",
                                                                                 compress_level=1)
    photo = bpy.data.images.load(str(addon / "big.png"))
    bpy.context.scene.relight_photo.max_megapixels = 5
    with pytest.raises(RuntimeError):
        _relight(photo.name)
    assert _status().message == ("'big.png' is 3000 x 2000 pixels (6 MP), over Max Photo Size (5 MP): to relight "
                                 "it, raise Max Photo Size in the panel to 6 MP (it will need about 1 GB of "
                                 "memory), or scale the photo down.")
    assert not bpy.data.images["big.png"].has_data


def test_a_header_claiming_more_pixels_than_its_file_can_hold_is_named_damaged_or_forged(addon):
    forged = addon / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(4000, 3000)))  # 12 MP in a few hundred bytes
    size = forged.stat().st_size
    photo = bpy.data.images.load(str(forged))
    with pytest.raises(RuntimeError):
        _relight(photo.name)
    assert _status().message == (
        f"'forged.jpg' claims 3000 x 4000 pixels (12 MP) in a file of {size:,} bytes, more than such a file can "
        "hold: it is damaged or forged. Open another photo (or, if it is whole, set Max Photo Size above 50 MP "
        "to decode it anyway).")


# ------------------------------------------------------------------ reopened without the photo

def _relit_saved_and_reopened(model, folder, what: str) -> tuple[str, str]:
    photo = bpy.data.images.load(str(folder / "person.png"))
    name = photo.name
    assert _relight(name) == {"FINISHED"}
    pid = photo[bl_images.PHOTO_ID]
    blend = folder / "shot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    path = folder / "person.png"
    if what == "deleted":
        path.unlink()
    elif what == "moved":
        (folder / "elsewhere").mkdir()
        path.rename(folder / "elsewhere" / "person.png")
    else:  # replaced by another photo under the same name
        from PIL import Image

        import numpy as np

        other = np.asarray(Image.open(path)).copy()
        other[:20] = 255
        Image.fromarray(other).save(path)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert state.SESSIONS[pid].photo_missing  # the saved result is shown; the photo is not the one relit
    return name, str(path)


@pytest.mark.parametrize("what", ["deleted", "moved", "replaced"])
@pytest.mark.parametrize("button", ["light_to_world", "compositing_setup"])
def test_photo_light_to_world_after_reopening_without_the_photo_says_what_happened(addon, model, what, button):
    name, path = _relit_saved_and_reopened(model, addon, what)
    worlds_before = len(bpy.data.worlds)
    with pytest.raises(RuntimeError):
        getattr(bpy.ops.relight_photo, button)(image_name=name)
    said = _status().message
    assert "still being read" not in said and "try again" not in said
    if what == "replaced":
        assert said == (f"The photo '{name}' changed since it was relit. To use its light, press Relight to "
                        "relight the photo as it is now.")
    else:
        assert said == (f"The photo file of '{name}' is missing ({path}): it was moved or deleted. To use its "
                        "light, point the image at the photo again (Image > Replace) and press Relight.")
    assert len(bpy.data.worlds) == worlds_before  # nothing made


# ------------------------------------------------------------------ a full disk while saving

class _FullDisk(io.FileIO):
    """A file on a disk with `room` bytes left: a write past them fails as Linux's would, and so
    does every write after (the disk stays full: the zip's closing records find no room either)."""

    room = 1024
    full = False

    def write(self, data):
        if self.full or self.tell() + len(data) > self.room:
            self.full = True
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


@pytest.mark.parametrize("ui", [False, True], ids=["here", "save threads"])
def test_a_full_disk_while_saving_names_every_photo_not_saved_and_leaves_no_open_zip(addon, monkeypatch, ui):
    import gc
    import shutil
    import sys
    import zipfile

    from blender_addon.blender import bl_saved, bl_session
    from blender_addon.logic import output_names

    names = []
    for stem in ("ana", "ben", "cleo", "dev"):
        shutil.copy(addon / "person.png", addon / f"{stem}.png")
        names.append(bpy.data.images.load(str(addon / f"{stem}.png")).name)
        assert _relight(names[-1]) == {"FINISHED"}
    full = {bpy.data.images[n][bl_images.PHOTO_ID]: n for n in names[:3]}  # cleo's, ben's, ana's: no room
    real_open = zipfile.io.open

    def open_on_a_full_disk(file, mode="r", *args, **kwargs):
        if "w" in mode and any(pid in os.path.basename(str(file)) for pid in full):
            return io.BufferedRandom(_FullDisk(file, mode.replace("b", "")))  # buffered, as open() is
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(zipfile.io, "open", open_on_a_full_disk)  # the zip module's own file opening
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    if ui:
        monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    blend = addon / "shot.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    bl_saved.wait_for_saves(bpy.context)
    gc.collect()
    if bpy.app.timers.is_registered(bl_saved.poll_saves):
        bpy.app.timers.unregister(bl_saved.poll_saves)
    said = _status().message
    assert _status().is_error
    assert said == ("The relights of 3 photos, 'ana.png', 'ben.png' and 'cleo.png', could not be saved next to "
                    "the .blend (No space left on device): they will need Relight after reopening.")
    # no "Exception ignored in ZipFile.__del__"
    assert [str(u.exc_value) for u in unraisable] == [], gc.garbage
    folder = os.path.dirname(output_names.saved_relight_path(str(blend), "x"))
    written = sorted(os.listdir(folder))
    dev = bpy.data.images["dev.png"][bl_images.PHOTO_ID]
    assert written == [f"{dev}.npz"]  # the one with room; no temporary file left of the others


def test_an_exr_photo_over_max_photo_size_is_refused_from_its_header(addon):
    import numpy as np

    from relight.files.exr import write_exr

    plane = np.full((1000, 1200), 0.2, np.float32)  # 1.2 MP of float
    write_exr(addon / "float.exr", {c: plane for c in "RGB"})
    photo = bpy.data.images.load(str(addon / "float.exr"))
    bpy.context.scene.relight_photo.max_megapixels = 1
    with pytest.raises(RuntimeError):
        _relight(photo.name)
    assert _status().message.startswith("'float.exr' is 1200 x 1000 pixels (1.2 MP), over Max Photo Size (1 MP)")
    assert not bpy.data.images["float.exr"].has_data  # refused from the header: Blender did not decode it
