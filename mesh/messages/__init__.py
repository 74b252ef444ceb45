"""Every wire message that is not a TD: scene and pose descriptions, twin descriptions."""
