"""Files in and out: :mod:`~sonarsim.io.output` (PNG and NPZ, written atomically),
:mod:`~sonarsim.io.figures` (composite pictures) and :mod:`~sonarsim.io.readers` (real ARIS
and Oculus recordings)."""
