"""The ground side: what a person or a lab's tools read of a flight.

A live view for Foxglove (:mod:`.live`), MCAP export with the original system's topics
(:mod:`.export`), a self-contained HTML flight report (:mod:`.report`). Each imports its
optional library (``foxglove-sdk``, ``mcap``) only when used: the flight path never loads them.
"""
