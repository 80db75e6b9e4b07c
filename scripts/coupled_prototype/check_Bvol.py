import numpy as np, math
from scipy.integrate import quad
rng=np.random.default_rng(0); ds=0.3
a,b,ge,gf=rng.uniform(0.5,1.5,4); t0,t1=0.17,0.83
def h1(t,a,b): d=b-a; return a*a*t*t/2+2*a*d*t**3/3+d*d*t**4/4
def h0(t,a,b): d=b-a; return a*a*t+a*d*t*t+d*d*t**3/3-h1(t,a,b)
I=ds*math.pi*(ge*(h0(t1,a,b)-h0(t0,a,b))+gf*(h1(t1,a,b)-h1(t0,a,b)))
Iq=quad(lambda t: ds*math.pi*(a+(b-a)*t)**2*(ge*(1-t)+gf*t),t0,t1,epsrel=1e-14)[0]
print(I,Iq)
full=ds*math.pi*(ge*(3*a*a+2*a*b+b*b)+gf*(a*a+2*a*b+3*b*b))/12
print(full, quad(lambda t: ds*math.pi*(a+(b-a)*t)**2*(ge*(1-t)+gf*t),0,1)[0])
# derivative formulas of h1 wrt a,b
e=1e-7;t=0.6
print((h1(t,a+e,b)-h1(t,a-e,b))/(2*e), a*t*t+2*(b-2*a)*t**3/3-(b-a)*t**4/2)
print((h1(t,a,b+e)-h1(t,a,b-e))/(2*e), 2*a*t**3/3+(b-a)*t**4/2)
