"""teamkf's own families: importing this module registers each of them (see :mod:`.registry`), in this order."""

from importlib import import_module

#: the modules of the built-in families, in the order ``teamkf.families()`` lists them
MODULES = ("kalman", "team", "kcf", "cikf", "local", "diffusion", "ci", "icf", "hcmci", "team_lossy")

for _name in MODULES:
    import_module(f"{__package__}.{_name}")
