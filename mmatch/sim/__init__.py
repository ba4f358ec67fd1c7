"""Scene simulator: two vehicles with a TI-like radar and a monocular camera each.

`world` lays out roads, structures and traffic; `radar` and `camera` render what one
vehicle's sensors report; `scenario` ties them into a world that moves over time;
`generate` writes `mmatch-scene/1` files; `realism` measures how hard they are.
"""
