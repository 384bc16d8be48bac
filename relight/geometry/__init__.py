"""Subpackage `relight.geometry`: the person's 3D shape read off one photo (a relief from the network's
normals) and what it implies for light: cast shadows. numpy only; imports nothing else of relight."""
