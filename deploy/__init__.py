"""Example cluster specs, shipped inside the package as ``hera.deploy`` (``hera examples``)."""
