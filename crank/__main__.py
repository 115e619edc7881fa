from crank.cli import main

main()
