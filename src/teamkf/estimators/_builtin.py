"""teamkf's own families: importing this module registers each of them (see :mod:`.registry`), in this order."""

from importlib import import_module

for _name in ("kalman", "team", "kcf", "cikf", "local", "diffusion", "ci", "icf", "hcmci", "team_lossy"):
    import_module(f"{__package__}.{_name}")
