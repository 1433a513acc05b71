"""What drives training end to end, a layer above ``train``: the demo (``make demo``),
``msta-compare``, ``msta-repro`` and its report, ``make device-check``."""
