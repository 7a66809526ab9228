"""Platform service messages (requests subclass ontology.platform.ServiceRequest); importing this
package registers every service action in the "platform" ontology."""
from . import common, email, hazard, home, information, interpretation, knowledge, localization, navigation, speech, vision  # noqa: F401
