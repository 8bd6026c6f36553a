"""One run: the Testbed that assembles and drives it, its intersections, the detector feed, the
stepped simulation."""
