"""The closed loop studied: the paper's section-4 experiment (:mod:`.experiment`), the envelope
of gross slips against finger speed (:mod:`.envelope`) and the Figs. 12/13 layout (:mod:`.figures`)."""

__all__: list[str] = []
