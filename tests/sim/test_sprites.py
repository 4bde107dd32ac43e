"""Object pictures read from the Freedoom WAD (omgifol): the demo's sprite query images."""

import numpy as np
import pytest

pytest.importorskip("vizdoom")
pytest.importorskip("omg")

from ravenmem.errors import InputError  # noqa: E402
from ravenmem.sim.sprites import SPRITES, freedoom_wad, has_sprite, sprite_image  # noqa: E402


def test_sprite_pictures() -> None:
    wad = freedoom_wad("freedoom2")
    img = sprite_image("Shotgun", wad, size=(160, 120), background=(90, 90, 90))
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    fg = np.any(img != 90, axis=-1)
    assert 0.05 < fg.mean() < 0.7  # the sprite, scaled up, in the middle of a plain background
    rows, cols = np.nonzero(fg)
    assert abs((rows.min() + rows.max()) / 2 - 60) < 10 and abs((cols.min() + cols.max()) / 2 - 80) < 10
    assert not np.array_equal(img, sprite_image("Medikit", wad))
    assert all(has_sprite(k, wad) for k in ("Shotgun", "Medikit", "ExplosiveBarrel", "RedCard"))
    assert len(SPRITES) > 40 and not has_sprite("DeadMarine", wad)
    with pytest.raises(InputError, match="no sprite"):
        sprite_image("NoSuchThing", wad)
