"""`sfdrig commission`: the first power-up of a rig and what it concludes."""
