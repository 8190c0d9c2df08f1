"""LeRobot v3.0 datasets of paired trajectories (``acn-collect``).

``schema.py`` says what a dataset holds (features and the typed ``acn`` metadata); ``record.py``
runs a collection and ``writer.py`` writes it all or nothing (``shards.py``: in parallel on Ray);
``reader.py`` reads a dataset back as transition arrays.
"""
