"""VDA 5050 vehicles (2.0.0 and 2.1.0) as gridfleet units: `gridfleet vda5050`, the adapter.

`core.py` is one vehicle as a unit (both protocols in, what to publish out); `frame.py` maps
squares to a vehicle's map coordinates and back; `orders.py` turns the squares gridfleet releases
to a unit into VDA 5050 orders that follow the specification's stitching rules; `states.py` reads
a vehicle's state for the fleet (which square it holds while between two); `wire.py` names the
topics and stamps the headers; `virtual.py` is a VDA 5050 vehicle of our own. Those are pure:
`shell.py` is the adapter's I/O (one MQTT endpoint for every vehicle of a vehicles file) and
`virtual_shell.py` puts the vehicle of our own on a broker. docs/vda5050.md says how it works and
the little that is not built yet.
"""
