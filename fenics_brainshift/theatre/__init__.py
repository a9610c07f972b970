"""The live service in theatre: OpenIGTLink in and out, the case it updates, its record."""
