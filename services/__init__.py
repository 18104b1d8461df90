"""Team Space Fortress's services. Importing the package registers the Gymnasium id `tsf/Role-v0`
(services/envs.py)."""

from services.envs import register as _register

_register()
