"""The equations of the adjustment: Schmid's conditions, their linearisation, the groups and normal
equations, the unknowns and observed elements, the datum (control, inner constraints on photos or
points), intersection and resection, plate corrections."""
