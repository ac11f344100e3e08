"""VDA 5050 vehicles as gridfleet units (issue 31, in progress): the pure parts first.

`frame.py` maps squares to a vehicle's map coordinates and back; `orders.py` turns the squares
gridfleet releases to a unit into VDA 5050 orders that follow the specification's stitching rules;
`states.py` reads a vehicle's state for the fleet (which square it holds while between two);
`wire.py` names the topics and stamps the headers. No I/O here: the adapter's shell comes next
(docs/vda5050.md says what is decided and what is not built yet).
"""
