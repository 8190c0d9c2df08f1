"""LeRobot v3.0 datasets of paired trajectories (``acn-collect``).

``schema.py`` says what a dataset holds (features) and ``metadata.py`` its typed ``acn``
metadata; ``record.py`` runs a collection, ``stream.py`` writes its episodes as they come and
``writer.py`` writes it all or nothing (``shards.py``: in parallel on Ray); ``reader.py`` reads
a dataset back as transition arrays.
"""
