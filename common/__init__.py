"""What the services share. Installed and imported as `viena.common` only (viena/common
is a link to this folder), so every module has one name and one set of classes."""
if __name__ != "viena.common":
    raise ImportError(f"import viena.common, not {__name__!r}: common/ is the package viena.common")
