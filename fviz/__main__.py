from fviz.cli import main

main()
