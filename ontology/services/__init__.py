"""Platform service messages (requests subclass ontology.platform.ServiceRequest); importing this
package registers every service action in the "platform" ontology: each module of the package is
imported, so a new service's module needs no line here (its implementation is one row of
agents/services/registry.py)."""
import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
del _module
