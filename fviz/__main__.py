from fviz.entry import main

main()
