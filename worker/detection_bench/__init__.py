"""Per-generator detection benchmark: every detection method on generated DSM pairs.

    detections.py  a method's detections.geojson read onto a pair's grid
    metrics.py     one method's detections scored on one pair (cells, slides, false alarms)
    runner.py      pairs made, methods run and scored, resumably, one pair in memory
    aggregate.py   runs summed up per generator x method, all and held-out generators
    tables.py      the plain-text tables of a report

A plain library (no web or queue frameworks); `slidewatch bench detection --suite
generators` is its command line.
"""
