"""Preferences from people (``icprl label``, docs/labelling.md): the pairs a person is asked about (``pairs.py``),
a session's directory (``session.py``), the append-only answer log (``answer_log.py``), the page's server
(``server.py``, its HTML/CSS/JS in ``assets/``), the export (``export.py``) and agreement (``agreement.py``),
and the page as the online agent's annotator (``online.py``)."""
