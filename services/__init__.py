"""One package per process. Installed and imported as `viena.services` only (viena/services
is a link to this folder), so every module has one name and one set of classes."""
if __name__ != "viena.services":
    raise ImportError(f"import viena.services, not {__name__!r}: services/ is the package viena.services")
