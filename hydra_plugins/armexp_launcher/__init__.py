"""armexp's Hydra launcher plugins (Hydra loads launchers only from the ``hydra_plugins``
namespace); see `hydra_plugins.armexp_launcher.ray_launcher`."""
