"""Summary frames out to the tools marine scientists use: FathomNet image records, COCO, VIAME/DIVE CSV."""
