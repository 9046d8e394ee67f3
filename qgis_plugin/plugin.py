"""The QGIS plugin object: registers the vectoradjust Processing provider.

``initProcessing`` is what ``qgis_process`` calls for plugins with
``hasProcessingProvider=yes``; the desktop calls ``initGui``, which does the same.
"""

from qgis.core import QgsApplication

from .provider import VectorAdjustProvider


class VectorAdjustPlugin:
    """Plugin entry point (no toolbar or menu: everything is in the Processing Toolbox)."""

    def __init__(self, iface=None):
        self.iface = iface
        self.provider = None

    def initProcessing(self):
        """Add the provider to the Processing registry (once)."""
        if self.provider is None:
            self.provider = VectorAdjustProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):
        """Called by QGIS desktop when the plugin is enabled."""
        self.initProcessing()

    def unload(self):
        """Remove the provider again."""
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
        from .styles import clear_post_processors

        clear_post_processors()
