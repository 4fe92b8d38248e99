"""Generated road networks: the builder registry, cache and netconvert call (``registry``), one module
per builder (``beltway``, ``highway_onramp``, ``rural_two_lane``, ``parking_street``), their typed
landmarks (``landmarks``) and the beltway's METANET segments on the SUMO ring (``segments``).
"""
